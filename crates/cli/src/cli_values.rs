//! Parsers for command-line values shared by several subcommands (clap `value_parser`s).

use glam::Vec3;
use semrecon_sparse::ChunkConfig;

/// `x,y,z` as three finite numbers.
pub fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("`{s}`: {e}; expected x,y,z"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("`{s}`: expected three finite numbers x,y,z")),
    }
}

/// A size in bytes: a whole number with an optional binary suffix `K`, `M`, `G` or `T`
/// (powers of 1024, `B` or `iB` after it allowed), e.g. `512M`, `2G`, `1.5G`, `300000000`.
pub fn parse_bytes(s: &str) -> Result<usize, String> {
    let t = s.trim();
    let upper = t.to_ascii_uppercase();
    let body = upper.strip_suffix("IB").or_else(|| upper.strip_suffix('B')).unwrap_or(&upper);
    let (number, shift) = match body.chars().last() {
        Some('K') => (&body[..body.len() - 1], 10),
        Some('M') => (&body[..body.len() - 1], 20),
        Some('G') => (&body[..body.len() - 1], 30),
        Some('T') => (&body[..body.len() - 1], 40),
        _ => (body, 0),
    };
    let value: f64 =
        number.trim().parse().map_err(|_| format!("`{s}`: expected a size such as 512M, 2G or 300000000"))?;
    let bytes = value * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < usize::MAX as f64) {
        return Err(format!("`{s}`: the size must be at least one byte"));
    }
    Ok(bytes as usize)
}

/// A chunk shape `SIDE/LEVELS/REGION_ROWS` of the chunked kernels (see [`ChunkConfig`]), e.g.
/// `16/2/512`: the side a power of two up to 64, 1 to 4 splitting levels, 1 to 65,536 rows.
pub fn parse_chunk_shape(s: &str) -> Result<ChunkConfig, String> {
    let bad = || format!("`{s}`: expected SIDE/LEVELS/REGION_ROWS, e.g. 16/2/512");
    let parts: Vec<&str> = s.trim().split('/').collect();
    let [side, levels, rows] = parts.as_slice() else { return Err(bad()) };
    let side: u32 = side.parse().map_err(|_| bad())?;
    let levels: u32 = levels.parse().map_err(|_| bad())?;
    let rows: usize = rows.parse().map_err(|_| bad())?;
    if !side.is_power_of_two() || side > 64 {
        return Err(format!("`{s}`: the side must be a power of two up to 64"));
    }
    if !(1..=4).contains(&levels) || side >> (levels - 1) == 0 {
        return Err(format!("`{s}`: 1 to 4 levels, and the smallest chunk at least 1 voxel wide"));
    }
    if !(1..=65_536).contains(&rows) {
        return Err(format!("`{s}`: region rows must be 1 to 65536"));
    }
    Ok(ChunkConfig { chunk_side: side, levels, max_region_rows: rows })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_parse_with_suffixes_and_reject_nonsense() {
        assert_eq!(parse_bytes("512M"), Ok(512 << 20));
        assert_eq!(parse_bytes("2G"), Ok(2 << 30));
        assert_eq!(parse_bytes("2GiB"), Ok(2 << 30));
        assert_eq!(parse_bytes("1.5g"), Ok(3 << 29));
        assert_eq!(parse_bytes("300000"), Ok(300000));
        assert_eq!(parse_bytes("64kb"), Ok(64 << 10));
        for bad in ["", "M", "-1G", "0", "two G", "1e400"] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn vec3_parses_and_rejects() {
        assert_eq!(parse_vec3("1, -2,3.5"), Ok(Vec3::new(1.0, -2.0, 3.5)));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,nan").is_err());
        assert!(parse_vec3("a,b,c").is_err());
    }

    #[test]
    fn chunk_shapes_parse_and_reject_nonsense() {
        let shape = parse_chunk_shape("16/2/512").expect("valid");
        assert_eq!((shape.chunk_side, shape.levels, shape.max_region_rows), (16, 2, 512));
        for bad in ["16/2", "12/2/512", "128/1/512", "4/4/512", "8/0/256", "8/3/0", "a/b/c", ""] {
            assert!(parse_chunk_shape(bad).is_err(), "{bad} accepted");
        }
    }
}
