// The voxel hash shared by the device hash tables (map.wgsl, hierarchy.wgsl), appended to each
// by the host (WGSL has no includes): a multiply-xor mix of the four coordinate words.

fn hash(c: vec4<i32>) -> u32 {
    var h = bitcast<u32>(c.x) * 0x8da6b343u;
    h ^= bitcast<u32>(c.y) * 0xd8163841u;
    h ^= bitcast<u32>(c.z) * 0xcb1ab31fu;
    h ^= bitcast<u32>(c.w) * 0x165667b1u;
    h ^= h >> 16u;
    h *= 0x7feb352du;
    h ^= h >> 15u;
    h *= 0x846ca68bu;
    h ^= h >> 16u;
    return h;
}
