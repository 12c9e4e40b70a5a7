//! Z-buffer RGB-D rendering of a [`LabeledMesh`]: depth along the optical axis, colour,
//! class label and incidence cosine per pixel, for synthetic scans and for comparing a
//! reconstruction with its ground truth.
//!
//! Why a rasteriser and not a ray caster: at 640x480 a room of 50k triangles must render at
//! hundreds of frames per second on a laptop CPU. The pipeline per frame is
//! 1. transform every vertex once into the camera frame and project it;
//! 2. set up every triangle (in parallel chunks): frustum culling, clipping against the near
//!    plane (cameras stand inside rooms, so many triangles cross the camera plane), and a
//!    guard band that keeps the fixed-point edge functions exact; no back-face culling,
//!    since scanned meshes have inconsistent winding;
//! 3. bin the screen-space triangles into horizontal bands and rasterise the bands in
//!    parallel with integer edge functions (8 sub-pixel bits, top-left fill rule), keeping
//!    per pixel only 1/z and the id of the nearest triangle;
//! 4. resolve ("deferred shading"): per pixel, intersect the pixel ray with the winning
//!    triangle's plane for the exact depth, perspective-correct barycentrics, colour and the
//!    incidence cosine.
//!
//! Each band owns its pixels, and equal depths are resolved by triangle index, so the image
//! is the same bits for any thread count.

use std::sync::Mutex;

use glam::{Affine3A, Vec3, Vec3A};
use rayon::prelude::*;

use crate::camera::Intrinsics;
use crate::class::UNLABELED;
use crate::frame::{Frame, FrameSource};
use crate::mesh::LabeledMesh;
use crate::sensor::SensorModel;

/// Sub-pixel precision of the rasteriser: vertex positions snap to 1/256 pixel.
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: f32 = (1 << SUBPIXEL_BITS) as f32;
/// Screen coordinates (pixels from the image centre, whatever the principal point) beyond
/// which a triangle is clipped in the camera frame; keeps fixed-point coordinates inside
/// `i32` and edge-function products far inside `i64`.
const GUARD_BAND: f32 = 32768.0;
/// Triangles per setup chunk; a chunk emits at most 6 screen triangles per input triangle,
/// which fits in the 14 low bits of a [`key`].
const CHUNK: usize = 2048;
const LOCAL_BITS: u32 = 14;
/// Pixel id meaning "no triangle".
const NO_HIT: u32 = u32::MAX;

/// Packs (chunk, index in chunk) so that keys grow with the triangle index.
#[inline]
fn key(chunk: usize, local: usize) -> u32 {
    ((chunk as u32) << LOCAL_BITS) | local as u32
}

/// A mesh laid out for rendering: validated, vertex positions SIMD-aligned, colours as
/// floats. Build once, render many frames.
#[derive(Debug, Clone)]
pub struct PreparedMesh {
    positions: Vec<Vec3A>,
    colors: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    labels: Vec<u8>,
}

impl PreparedMesh {
    /// Validates `mesh` (see [`LabeledMesh::validate`]) and copies what rendering needs.
    /// Triangles without labels render as [`UNLABELED`].
    pub fn new(mesh: &LabeledMesh) -> crate::Result<Self> {
        mesh.validate().map_err(|m| crate::DataError::InvalidArgument(format!("mesh to render: {m}")))?;
        if mesh.triangles.len() >= (1usize << (32 - LOCAL_BITS)) * CHUNK {
            return Err(crate::DataError::InvalidArgument(format!(
                "mesh to render has {} triangles, more than the renderer supports",
                mesh.triangles.len()
            )));
        }
        let labels = if mesh.triangle_labels.is_empty() {
            vec![UNLABELED; mesh.triangles.len()]
        } else {
            mesh.triangle_labels.clone()
        };
        Ok(Self {
            positions: mesh.positions.iter().map(|&p| Vec3A::from(p)).collect(),
            colors: mesh.colors.iter().map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32)).collect(),
            triangles: mesh.triangles.clone(),
            labels,
        })
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }
}

/// What one render produces.
///
/// # Shapes
/// Every buffer is row-major, `width * height` long.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RenderOutput {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Depth along the optical axis in metres; 0 where no surface is seen.
    pub depth: Vec<f32>,
    /// Perspective-correct interpolation of the vertex colours; black where no surface.
    pub color: Vec<[u8; 3]>,
    /// Class label of the visible triangle; [`UNLABELED`] where no surface.
    pub labels: Vec<u8>,
    /// `|n . v|` for the surface normal `n` and the unit viewing ray `v` (1 = seen head-on,
    /// 0 = grazing); 0 where no surface.
    pub incidence: Vec<f32>,
}

impl RenderOutput {
    /// Copies the buffers into a [`Frame`] with the given index, pose and intrinsics
    /// (timestamp `index / 30` s).
    pub fn to_frame(&self, index: usize, intrinsics: Intrinsics, world_from_camera: Affine3A) -> Frame {
        Frame {
            index,
            timestamp: index as f64 / 30.0,
            depth: self.depth.clone(),
            color: self.color.clone(),
            intrinsics,
            world_from_camera: Some(world_from_camera),
            labels: Some(self.labels.clone()),
        }
    }

    fn resize(&mut self, width: u32, height: u32) {
        let n = width as usize * height as usize;
        self.width = width;
        self.height = height;
        self.depth.resize(n, 0.0);
        self.color.resize(n, [0; 3]);
        self.labels.resize(n, UNLABELED);
        self.incidence.resize(n, 0.0);
    }
}

/// A vertex in the camera frame with its projection (valid when `code` has no
/// [`CODE_NEAR`]/[`CODE_GUARD`] bit).
#[derive(Debug, Clone, Copy, Default)]
struct CamVertex {
    p: Vec3A,
    /// Fixed-point screen position.
    sx: i32,
    sy: i32,
    inv_z: f32,
    /// Outcode: which frustum half-spaces the vertex is outside of.
    code: u32,
}

const CODE_NEAR: u32 = 1;
const CODE_LEFT: u32 = 2;
const CODE_RIGHT: u32 = 4;
const CODE_TOP: u32 = 8;
const CODE_BOTTOM: u32 = 16;
/// Not an outcode for culling: the projection is outside the guard band.
const CODE_GUARD: u32 = 32;

/// A screen-space triangle ready for rasterisation.
#[derive(Debug, Clone, Copy)]
struct RasterTri {
    /// Edge functions `a * X + b * Y + c >= 0` inside, at fixed-point pixel centres
    /// (`a` and `b` are pre-multiplied by the sub-pixel scale; the fill-rule bias is in `c`).
    ea: [i64; 3],
    eb: [i64; 3],
    ec: [i64; 3],
    /// 1/z = za * x + zb * y + zc at pixel (x, y).
    za: f32,
    zb: f32,
    zc: f32,
    /// `1 / ea` (0 where `ea` is 0), for finding where a row enters and leaves.
    inv_ea: [f64; 3],
    /// Pixel bounding box, inclusive, clipped to the image.
    x0: u16,
    x1: u16,
    y0: u16,
    y1: u16,
    /// Index of the [`ShadeTri`] in the same chunk.
    shade: u32,
}

/// The camera-frame plane of an original (unclipped) triangle, for the resolve pass.
#[derive(Debug, Clone, Copy)]
struct ShadeTri {
    /// Unnormalised normal `(p1 - p0) x (p2 - p0)`.
    n: Vec3A,
    /// Barycentric 1 and 2 of a point `q` in the plane: `q . m1 - q1`, `q . m2 - q2`.
    m1: Vec3A,
    m2: Vec3A,
    /// Colour of vertex 0 and its changes towards vertices 1 and 2.
    c0: Vec3,
    dc1: Vec3,
    dc2: Vec3,
    q1: f32,
    q2: f32,
    n_dot_p0: f32,
    inv_n_len: f32,
    label: u8,
}

#[derive(Debug, Default)]
struct SetupChunk {
    raster: Vec<RasterTri>,
    shade: Vec<ShadeTri>,
}

/// Z-buffer renderer for one camera. Keeps its buffers between frames, so rendering a
/// sequence allocates nothing after the first frame.
#[derive(Debug)]
pub struct Renderer {
    intrinsics: Intrinsics,
    z_near: f32,
    band_height: u32,
    vertices: Vec<CamVertex>,
    chunks: Vec<SetupChunk>,
    bins: Vec<Vec<u32>>,
    inv_z: Vec<f32>,
    ids: Vec<u32>,
    /// x component of the pixel rays (z = 1) per image column.
    ray_x: Vec<f32>,
    output: RenderOutput,
}

impl Renderer {
    /// Largest image side: keeps pixel coordinates well inside the guard band, where the
    /// fixed-point edge functions are exact.
    pub const MAX_SIZE: u32 = 16384;

    /// A renderer for `intrinsics` with a near plane at 0.05 m; images up to
    /// [`Renderer::MAX_SIZE`] pixels wide and high.
    pub fn new(intrinsics: Intrinsics) -> crate::Result<Self> {
        if intrinsics.width > Self::MAX_SIZE || intrinsics.height > Self::MAX_SIZE {
            return Err(crate::DataError::InvalidArgument(format!(
                "cannot render {}x{} images (at most {} pixels a side)",
                intrinsics.width,
                intrinsics.height,
                Self::MAX_SIZE
            )));
        }
        let n = intrinsics.pixel_count();
        Ok(Self {
            intrinsics,
            z_near: 0.05,
            band_height: 16,
            vertices: Vec::new(),
            chunks: Vec::new(),
            bins: Vec::new(),
            inv_z: vec![0.0; n],
            ids: vec![NO_HIT; n],
            ray_x: Vec::new(),
            output: RenderOutput::default(),
        })
    }

    /// Sets the near clipping distance in metres (surfaces closer than this are cut away).
    pub fn with_near(mut self, z_near: f32) -> crate::Result<Self> {
        if !(z_near.is_finite() && z_near > 0.0) {
            return Err(crate::DataError::InvalidArgument(format!("near plane {z_near} must be positive")));
        }
        self.z_near = z_near;
        Ok(self)
    }

    /// The camera this renderer draws for.
    pub fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    /// Renders `mesh` seen from `world_from_camera` (camera frame x right, y down, z forward)
    /// into the renderer's buffers and returns them.
    pub fn render(&mut self, mesh: &PreparedMesh, world_from_camera: Affine3A) -> &RenderOutput {
        self.transform(mesh, world_from_camera.inverse());
        self.setup(mesh);
        self.bin();
        self.rasterise();
        self.resolve();
        &self.output
    }

    /// Renders and copies the result into a [`Frame`] with index `index`.
    pub fn render_frame(&mut self, mesh: &PreparedMesh, world_from_camera: Affine3A, index: usize) -> Frame {
        let k = self.intrinsics;
        self.render(mesh, world_from_camera).to_frame(index, k, world_from_camera)
    }

    fn transform(&mut self, mesh: &PreparedMesh, camera_from_world: Affine3A) {
        let k = self.intrinsics;
        let z_near = self.z_near;
        // Frustum planes through the outer pixel borders, as x/z and y/z bounds.
        let left = (-0.5 - k.cx) / k.fx;
        let right = (k.width as f32 - 0.5 - k.cx) / k.fx;
        let top = (-0.5 - k.cy) / k.fy;
        let bottom = (k.height as f32 - 0.5 - k.cy) / k.fy;
        let (half_w, half_h) = (k.width as f32 * 0.5, k.height as f32 * 0.5);
        self.vertices.resize(mesh.positions.len(), CamVertex::default());
        self.vertices.par_chunks_mut(4096).zip(mesh.positions.par_chunks(4096)).for_each(|(out, inp)| {
            for (v, &p_world) in out.iter_mut().zip(inp) {
                let p = camera_from_world.transform_point3a(p_world);
                let mut code = 0;
                if p.z < z_near {
                    code |= CODE_NEAR;
                }
                if p.x < left * p.z {
                    code |= CODE_LEFT;
                }
                if p.x > right * p.z {
                    code |= CODE_RIGHT;
                }
                if p.y < top * p.z {
                    code |= CODE_TOP;
                }
                if p.y > bottom * p.z {
                    code |= CODE_BOTTOM;
                }
                let mut sx = 0;
                let mut sy = 0;
                let mut inv_z = 0.0;
                if code & CODE_NEAR == 0 {
                    inv_z = 1.0 / p.z;
                    let x = k.fx * p.x * inv_z + k.cx;
                    let y = k.fy * p.y * inv_z + k.cy;
                    if (x - half_w).abs() < GUARD_BAND && (y - half_h).abs() < GUARD_BAND {
                        sx = round_to_i32(x * SUBPIXEL);
                        sy = round_to_i32(y * SUBPIXEL);
                    } else {
                        code |= CODE_GUARD;
                    }
                }
                *v = CamVertex { p, sx, sy, inv_z, code };
            }
        });
    }

    fn setup(&mut self, mesh: &PreparedMesh) {
        let n_chunks = mesh.triangles.len().div_ceil(CHUNK);
        self.chunks.resize_with(n_chunks, SetupChunk::default);
        let vertices = &self.vertices;
        let k = self.intrinsics;
        let z_near = self.z_near;
        self.chunks.par_iter_mut().zip(mesh.triangles.par_chunks(CHUNK)).enumerate().for_each(|(ci, (chunk, tris))| {
            chunk.raster.clear();
            chunk.shade.clear();
            for (ti, tri) in tris.iter().enumerate() {
                let v = tri.map(|i| vertices[i as usize]);
                let outside = v[0].code & v[1].code & v[2].code & !CODE_GUARD;
                if outside != 0 {
                    continue;
                }
                let before = chunk.raster.len();
                let shade_index = chunk.shade.len() as u32;
                if (v[0].code | v[1].code | v[2].code) & (CODE_NEAR | CODE_GUARD) == 0 {
                    setup_screen_triangle(
                        &k,
                        [v[0].sx, v[1].sx, v[2].sx],
                        [v[0].sy, v[1].sy, v[2].sy],
                        [v[0].inv_z, v[1].inv_z, v[2].inv_z],
                        shade_index,
                        &mut chunk.raster,
                    );
                } else {
                    clip_and_setup(&k, z_near, [v[0].p, v[1].p, v[2].p], shade_index, &mut chunk.raster);
                }
                if chunk.raster.len() > before {
                    let colors = tri.map(|i| mesh.colors[i as usize]);
                    let label = mesh.labels[ci * CHUNK + ti];
                    if let Some(s) = shade_triangle([v[0].p, v[1].p, v[2].p], colors, label) {
                        chunk.shade.push(s);
                    } else {
                        chunk.raster.truncate(before);
                    }
                }
            }
        });
    }

    fn bin(&mut self) {
        let h = self.intrinsics.height;
        let n_bands = h.div_ceil(self.band_height) as usize;
        self.bins.resize_with(n_bands, Vec::new);
        for b in &mut self.bins {
            b.clear();
        }
        let bh = self.band_height as usize;
        for (ci, chunk) in self.chunks.iter().enumerate() {
            for (ri, t) in chunk.raster.iter().enumerate() {
                let k = key(ci, ri);
                for band in (t.y0 as usize / bh)..=(t.y1 as usize / bh) {
                    self.bins[band].push(k);
                }
            }
        }
    }

    fn rasterise(&mut self) {
        let w = self.intrinsics.width as usize;
        let bh = self.band_height as usize;
        let n = self.intrinsics.pixel_count();
        self.inv_z.resize(n, 0.0);
        self.ids.resize(n, NO_HIT);
        let chunks = &self.chunks;
        self.inv_z
            .par_chunks_mut(w * bh)
            .zip(self.ids.par_chunks_mut(w * bh))
            .zip(self.bins.par_iter())
            .enumerate()
            .for_each(|(band, ((zbuf, ids), bin))| {
                zbuf.fill(0.0);
                ids.fill(NO_HIT);
                let band_y0 = band * bh;
                let band_y1 = band_y0 + zbuf.len() / w; // exclusive
                for &k in bin {
                    let ci = (k >> LOCAL_BITS) as usize;
                    let ri = (k & ((1 << LOCAL_BITS) - 1)) as usize;
                    let t = &chunks[ci].raster[ri];
                    let id = key(ci, t.shade as usize);
                    raster_triangle(t, id, band_y0, band_y1, w, zbuf, ids);
                }
            });
    }

    fn resolve(&mut self) {
        let k = self.intrinsics;
        let w = k.width as usize;
        self.output.resize(k.width, k.height);
        if self.ray_x.len() != w {
            self.ray_x = (0..w).map(|x| (x as f32 - k.cx) / k.fx).collect();
        }
        let ray_x = &self.ray_x;
        let chunks = &self.chunks;
        let ids = &self.ids;
        let inv_z = &self.inv_z;
        let out = &mut self.output;
        out.depth
            .par_chunks_mut(w)
            .zip(out.color.par_chunks_mut(w))
            .zip(out.labels.par_chunks_mut(w))
            .zip(out.incidence.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (((depth, color), labels), incidence))| {
                // The pixel ray is d = (ray_x[x], dy, 1): its parameter along d is z.
                let dy = (y as f32 - k.cy) / k.fy;
                let dy2 = dy * dy + 1.0;
                let ids = &ids[y * w..(y + 1) * w];
                let inv_z = &inv_z[y * w..(y + 1) * w];
                let mut x = 0;
                // Runs of pixels of one triangle share the triangle's constants.
                while x < w {
                    let id = ids[x];
                    let mut end = x + 1;
                    while end < w && ids[end] == id {
                        end += 1;
                    }
                    if id == NO_HIT {
                        depth[x..end].fill(0.0);
                        color[x..end].fill([0; 3]);
                        labels[x..end].fill(UNLABELED);
                        incidence[x..end].fill(0.0);
                        x = end;
                        continue;
                    }
                    let s = &chunks[(id >> LOCAL_BITS) as usize].shade[(id & ((1 << LOCAL_BITS) - 1)) as usize];
                    labels[x..end].fill(s.label);
                    // n.d, m1.d and m2.d are affine in ray_x along the row.
                    let nd_row = s.n.y * dy + s.n.z;
                    let m1_row = s.m1.y * dy + s.m1.z;
                    let m2_row = s.m2.y * dy + s.m2.z;
                    let (c0, dc1, dc2, q1, q2) = (s.c0, s.dc1, s.dc2, s.q1, s.q2);
                    // Depth and incidence first, in a loop the compiler vectorises.
                    let (dxs, zs, inc, izs) =
                        (&ray_x[x..end], &mut depth[x..end], &mut incidence[x..end], &inv_z[x..end]);
                    for j in 0..dxs.len() {
                        let dx = dxs[j];
                        let nd = s.n.x * dx + nd_row;
                        let z = s.n_dot_p0 / nd;
                        // Seen exactly edge-on, the rasterised 1/z is all there is.
                        zs[j] = if z > 0.0 && z < f32::MAX { z } else { 1.0 / izs[j] };
                        inc[j] = (nd.abs() * s.inv_n_len / (dx * dx + dy2).sqrt()).min(1.0);
                    }
                    for ((c, &z), &dx) in color[x..end].iter_mut().zip(zs.iter()).zip(dxs) {
                        // Barycentrics of the hit z * d: (z d - p0) . m.
                        let b1 = z * (s.m1.x * dx + m1_row) - q1;
                        let b2 = z * (s.m2.x * dx + m2_row) - q2;
                        *c = to_u8_rounded(c0 + dc1 * b1 + dc2 * b2);
                    }
                    x = end;
                }
            });
    }
}

/// Rounds a colour to bytes, clamping to 0..=255. Adding 2^23 puts the rounded integer into
/// the low mantissa bits, which is cheaper than three saturating float-to-int casts.
#[inline]
fn to_u8_rounded(c: Vec3) -> [u8; 3] {
    let c = c.clamp(Vec3::ZERO, Vec3::splat(255.0)) + 8_388_608.0;
    [c.x.to_bits() as u8, c.y.to_bits() as u8, c.z.to_bits() as u8]
}

/// Rounds half away from zero; a cast instead of `f32::round`, which is a libm call on
/// baseline x86-64.
#[inline]
fn round_to_i32(v: f32) -> i32 {
    (v + 0.5f32.copysign(v)) as i32
}

/// Plane and colour data of the camera-frame triangle `p` (the plane of the original
/// triangle, so one record serves every piece that clipping makes of it); `None` when it is
/// degenerate.
fn shade_triangle(p: [Vec3A; 3], colors: [Vec3; 3], label: u8) -> Option<ShadeTri> {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    let n = e1.cross(e2);
    let nn = n.length_squared();
    if !(nn > 0.0 && nn.is_finite()) {
        return None;
    }
    let m1 = e2.cross(n) / nn;
    let m2 = n.cross(e1) / nn;
    Some(ShadeTri {
        n,
        m1,
        m2,
        c0: colors[0],
        dc1: colors[1] - colors[0],
        dc2: colors[2] - colors[0],
        q1: p[0].dot(m1),
        q2: p[0].dot(m2),
        n_dot_p0: n.dot(p[0]),
        inv_n_len: nn.sqrt().recip(),
        label,
    })
}

/// Clips the camera-frame triangle `p` against the near plane and the guard band
/// (Sutherland-Hodgman), and sets up the fan of screen triangles of what is left.
fn clip_and_setup(k: &Intrinsics, z_near: f32, p: [Vec3A; 3], shade: u32, out: &mut Vec<RasterTri>) {
    // Half-spaces `plane . (x, y, z, 1) >= 0`: near, then |screen - centre| < guard band,
    // slightly inside the projection's guard test so that clipped vertices pass it.
    let g = GUARD_BAND * 0.99;
    // Screen x - width/2 = fx X/Z + ox, so |screen x - width/2| < g is
    // fx X + (g + ox) Z > 0 and -fx X + (g - ox) Z > 0; the same for y.
    let ox = k.cx - k.width as f32 * 0.5;
    let oy = k.cy - k.height as f32 * 0.5;
    let planes = [
        [0.0, 0.0, 1.0, -z_near],
        [k.fx, 0.0, g + ox, 0.0],
        [-k.fx, 0.0, g - ox, 0.0],
        [0.0, k.fy, g + oy, 0.0],
        [0.0, -k.fy, g - oy, 0.0],
    ];
    let mut poly: [Vec3A; 9] = [Vec3A::ZERO; 9];
    let mut next: [Vec3A; 9] = [Vec3A::ZERO; 9];
    poly[..3].copy_from_slice(&p);
    let mut len = 3;
    for pl in planes {
        let dist = |q: Vec3A| pl[0] * q.x + pl[1] * q.y + pl[2] * q.z + pl[3];
        let mut m = 0;
        for i in 0..len {
            let a = poly[i];
            let b = poly[(i + 1) % len];
            let (da, db) = (dist(a), dist(b));
            if da >= 0.0 {
                next[m] = a;
                m += 1;
            }
            if (da >= 0.0) != (db >= 0.0) {
                let t = da / (da - db);
                next[m] = a + (b - a) * t;
                m += 1;
            }
        }
        len = m;
        if len < 3 {
            return;
        }
        poly[..len].copy_from_slice(&next[..len]);
    }
    let mut sx = [0i32; 9];
    let mut sy = [0i32; 9];
    let mut iz = [0f32; 9];
    for i in 0..len {
        let q = poly[i];
        let inv = 1.0 / q.z.max(z_near);
        iz[i] = inv;
        sx[i] = round_to_i32((k.fx * q.x * inv + k.cx) * SUBPIXEL);
        sy[i] = round_to_i32((k.fy * q.y * inv + k.cy) * SUBPIXEL);
    }
    for i in 1..len - 1 {
        setup_screen_triangle(
            k,
            [sx[0], sx[i], sx[i + 1]],
            [sy[0], sy[i], sy[i + 1]],
            [iz[0], iz[i], iz[i + 1]],
            shade,
            out,
        );
    }
}

/// Sets up the edge functions of a screen triangle (fixed-point vertices) and pushes it
/// when it covers at least one pixel centre's bounding box.
fn setup_screen_triangle(
    k: &Intrinsics,
    sx: [i32; 3],
    sy: [i32; 3],
    iz: [f32; 3],
    shade: u32,
    out: &mut Vec<RasterTri>,
) {
    let (x, y) = (sx.map(i64::from), sy.map(i64::from));
    let area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    if area == 0 {
        return;
    }
    // No back-face culling: make every triangle positive so that inside is E >= 0.
    let (x, y, iz) =
        if area < 0 { ([x[0], x[2], x[1]], [y[0], y[2], y[1]], [iz[0], iz[2], iz[1]]) } else { (x, y, iz) };
    let s = 1i64 << SUBPIXEL_BITS;
    let xmin = x.iter().copied().min().unwrap_or(0);
    let xmax = x.iter().copied().max().unwrap_or(0);
    let ymin = y.iter().copied().min().unwrap_or(0);
    let ymax = y.iter().copied().max().unwrap_or(0);
    // Pixel centres at multiples of `s`: the first centre >= min, the last <= max.
    let px0 = (xmin + s - 1).div_euclid(s).max(0);
    let px1 = xmax.div_euclid(s).min(k.width as i64 - 1);
    let py0 = (ymin + s - 1).div_euclid(s).max(0);
    let py1 = ymax.div_euclid(s).min(k.height as i64 - 1);
    if px0 > px1 || py0 > py1 {
        return;
    }
    let mut ea = [0i64; 3];
    let mut eb = [0i64; 3];
    let mut ec = [0i64; 3];
    for e in 0..3 {
        let (i, j) = (e, (e + 1) % 3);
        // E(p) = (b - a) x (p - a), positive inside for a positive triangle.
        let a = y[i] - y[j];
        let b = x[j] - x[i];
        let c = x[i] * y[j] - y[i] * x[j];
        // Top-left rule: pixels exactly on a left edge (E grows with x) or a top edge
        // (horizontal, E grows downwards) belong to the triangle, others do not.
        let top_left = a > 0 || (a == 0 && b > 0);
        ea[e] = a * s;
        eb[e] = b * s;
        ec[e] = c - if top_left { 0 } else { 1 };
    }
    // 1/z is affine in screen space: fit its plane through the three vertices (in f64, as
    // pixel coordinates reach thousands and 1/z differences are small).
    let xf = x.map(|v| v as f64 / s as f64);
    let yf = y.map(|v| v as f64 / s as f64);
    let zf = iz.map(f64::from);
    let det = (xf[1] - xf[0]) * (yf[2] - yf[0]) - (yf[1] - yf[0]) * (xf[2] - xf[0]);
    let za = ((zf[1] - zf[0]) * (yf[2] - yf[0]) - (zf[2] - zf[0]) * (yf[1] - yf[0])) / det;
    let zb = ((zf[2] - zf[0]) * (xf[1] - xf[0]) - (zf[1] - zf[0]) * (xf[2] - xf[0])) / det;
    let zc = zf[0] - za * xf[0] - zb * yf[0];
    out.push(RasterTri {
        ea,
        eb,
        ec,
        inv_ea: ea.map(|a| if a != 0 { 1.0 / a as f64 } else { 0.0 }),
        za: za as f32,
        zb: zb as f32,
        zc: zc as f32,
        x0: px0 as u16,
        x1: px1 as u16,
        y0: py0 as u16,
        y1: py1 as u16,
        shade,
    });
}

/// Rasterises the rows of `t` inside the band `[band_y0, band_y1)`: per row, the run of
/// pixel centres inside the triangle, then a depth test over the run.
///
/// # Shapes
/// `zbuf` and `ids` hold the band's rows, `(band_y1 - band_y0) * w` long.
#[inline]
fn raster_triangle(
    t: &RasterTri,
    id: u32,
    band_y0: usize,
    band_y1: usize,
    w: usize,
    zbuf: &mut [f32],
    ids: &mut [u32],
) {
    let y_start = (t.y0 as usize).max(band_y0);
    let y_end = (t.y1 as usize + 1).min(band_y1);
    'rows: for y in y_start..y_end {
        let yf = y as i64;
        // The exact run of pixel centres inside all three edges: each edge function is
        // monotonic along the row, so start from the floating-point crossing and settle it
        // with the integer edge functions.
        let (mut lo, mut hi) = (t.x0 as i64, t.x1 as i64);
        for e in 0..3 {
            let a = t.ea[e];
            let r = t.eb[e] * yf + t.ec[e];
            let guess = -(r as f64) * t.inv_ea[e];
            if a > 0 {
                // First x with a x + r >= 0.
                let mut x = (guess as i64).clamp(lo, hi + 1);
                while x <= hi && a * x + r < 0 {
                    x += 1;
                }
                while x > lo && a * (x - 1) + r >= 0 {
                    x -= 1;
                }
                lo = x;
            } else if a < 0 {
                // Last x with a x + r >= 0.
                let mut x = (guess as i64).clamp(lo - 1, hi);
                while x >= lo && a * x + r < 0 {
                    x -= 1;
                }
                while x < hi && a * (x + 1) + r >= 0 {
                    x += 1;
                }
                hi = x;
            } else if r < 0 {
                continue 'rows;
            }
            if lo > hi {
                continue 'rows;
            }
        }
        let (lo, hi) = (lo as usize, hi as usize);
        let zrow = t.zb * y as f32 + t.zc;
        let row = (y - band_y0) * w;
        // Branch-free depth test (ties go to the lower id), so that it vectorises.
        let span = row + lo..row + hi + 1;
        for ((zb, ib), x) in zbuf[span.clone()].iter_mut().zip(&mut ids[span]).zip(lo..) {
            let iz = t.za * x as f32 + zrow;
            let take = iz > *zb || (iz == *zb && id < *ib);
            *zb = if take { iz } else { *zb };
            *ib = if take { id } else { *ib };
        }
    }
}

/// A synthetic RGB-D sequence: a mesh rendered along a trajectory, with a sensor model, as
/// a [`FrameSource`] that the reconstruction reads like any dataset (ground-truth poses and
/// per-pixel labels included).
#[derive(Debug)]
pub struct RenderedScan {
    name: String,
    mesh: PreparedMesh,
    poses: Vec<Affine3A>,
    sensor: SensorModel,
    frame_rate: f64,
    renderer: Mutex<Renderer>,
}

impl RenderedScan {
    /// Renders `mesh` from `poses` (`world_from_camera`, one per frame, at `frame_rate` Hz)
    /// with `intrinsics`, passing every frame through `sensor`.
    pub fn new(
        name: impl Into<String>,
        mesh: &LabeledMesh,
        poses: Vec<Affine3A>,
        intrinsics: Intrinsics,
        sensor: SensorModel,
        frame_rate: f64,
    ) -> crate::Result<Self> {
        if !(frame_rate.is_finite() && frame_rate > 0.0) {
            return Err(crate::DataError::InvalidArgument(format!("frame rate {frame_rate} must be positive")));
        }
        if let Some(i) = poses.iter().position(|p| !p.is_finite()) {
            return Err(crate::DataError::InvalidArgument(format!("pose {i} of the scan is not finite")));
        }
        Ok(Self {
            name: name.into(),
            mesh: PreparedMesh::new(mesh)?,
            poses,
            sensor,
            frame_rate,
            renderer: Mutex::new(Renderer::new(intrinsics)?),
        })
    }
}

impl RenderedScan {
    /// The same scan under another name (what [`FrameSource::name`] reports).
    pub fn renamed(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }
}

impl FrameSource for RenderedScan {
    fn name(&self) -> String {
        self.name.clone()
    }

    fn len(&self) -> usize {
        self.poses.len()
    }

    fn intrinsics(&self) -> Intrinsics {
        self.renderer.lock().unwrap_or_else(|e| e.into_inner()).intrinsics()
    }

    fn has_ground_truth(&self) -> bool {
        true
    }

    fn frame_rate(&self) -> f64 {
        self.frame_rate
    }

    fn frame(&self, index: usize) -> crate::Result<Frame> {
        let pose = *self.poses.get(index).ok_or_else(|| {
            crate::DataError::InvalidArgument(format!("{}: no frame {index} (it has {})", self.name, self.poses.len()))
        })?;
        // A panic elsewhere cannot leave the buffers in a state that matters: every render
        // overwrites them.
        let mut renderer = self.renderer.lock().unwrap_or_else(|e| e.into_inner());
        let k = renderer.intrinsics();
        let out = renderer.render(&self.mesh, pose);
        let mut frame = if self.sensor == SensorModel::ideal() {
            out.to_frame(index, k, pose)
        } else {
            let mut noisy = out.clone();
            self.sensor.apply(&mut noisy, index);
            noisy.to_frame(index, k, pose)
        };
        frame.timestamp = index as f64 / self.frame_rate;
        Ok(frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_mesh(z: f32) -> LabeledMesh {
        LabeledMesh {
            positions: vec![
                Vec3::new(-10.0, -10.0, z),
                Vec3::new(10.0, -10.0, z),
                Vec3::new(10.0, 10.0, z),
                Vec3::new(-10.0, 10.0, z),
            ],
            colors: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]],
            triangles: vec![[0, 1, 2], [0, 3, 2]],
            triangle_labels: vec![3, 4],
            ..Default::default()
        }
    }

    #[test]
    fn a_plane_filling_the_view_has_constant_depth_and_no_holes() {
        let k = Intrinsics::new(64, 48, 40.0, 40.0, 31.5, 23.5).expect("valid");
        let mesh = PreparedMesh::new(&quad_mesh(2.0)).expect("valid");
        let mut r = Renderer::new(k).expect("renderer");
        let out = r.render(&mesh, Affine3A::IDENTITY);
        assert!(out.depth.iter().all(|&d| (d - 2.0).abs() < 1e-5), "holes or wrong depth");
        assert!(out.labels.iter().all(|&l| l == 3 || l == 4));
        assert!(out.incidence.iter().all(|&c| c > 0.65 && c <= 1.0));
        assert_eq!(to_u8_rounded(Vec3::new(-3.0, 254.6, 1e9)), [0, 255, 255]);
        assert_eq!(to_u8_rounded(Vec3::new(f32::NAN, 0.4, 127.6)), [0, 0, 128]);
        // The centre pixel sees the middle of the quad's diagonal: a colour mix.
        let c = out.color[24 * 64 + 32];
        assert!(c.iter().any(|&v| v > 20 && v < 235), "colour {c:?} not interpolated");
    }

    #[test]
    fn a_rendered_scan_is_a_frame_source() {
        let k = Intrinsics::new(32, 24, 20.0, 20.0, 15.5, 11.5).expect("valid");
        let poses = vec![Affine3A::IDENTITY, Affine3A::from_translation(Vec3::new(0.0, 0.0, 0.5))];
        let scan = RenderedScan::new("synth:quad", &quad_mesh(2.0), poses, k, SensorModel::kinect(), 30.0)
            .expect("valid scan");
        assert_eq!(scan.len(), 2);
        let f = scan.frame(1).expect("frame");
        f.validate().expect("valid frame");
        assert!((f.timestamp - 1.0 / 30.0).abs() < 1e-12);
        let valid: Vec<f32> = f.depth.iter().copied().filter(|&d| d > 0.0).collect();
        assert!(valid.len() > 600 && valid.iter().all(|&d| (d - 1.5).abs() < 0.05), "noisy depth around 1.5 m");
        assert_eq!(f.labels.as_ref().map(|l| l.len()), Some(32 * 24));
        assert!(scan.frame(2).is_err());
        let ideal =
            RenderedScan::new("synth:quad", &quad_mesh(2.0), vec![Affine3A::IDENTITY], k, SensorModel::ideal(), 30.0)
                .expect("valid scan");
        assert!(ideal.frame(0).expect("frame").depth.iter().all(|&d| (d - 2.0).abs() < 1e-5));
    }

    #[test]
    fn nothing_behind_the_camera_is_drawn() {
        let k = Intrinsics::new(32, 24, 20.0, 20.0, 15.5, 11.5).expect("valid");
        let mesh = PreparedMesh::new(&quad_mesh(-2.0)).expect("valid");
        let mut r = Renderer::new(k).expect("renderer");
        let out = r.render(&mesh, Affine3A::IDENTITY);
        assert!(out.depth.iter().all(|&d| d == 0.0));
        let huge = Intrinsics::new(20000, 10, 1.0, 1.0, 0.0, 0.0).expect("valid");
        assert!(Renderer::new(huge).is_err());
        assert!(out.labels.iter().all(|&l| l == UNLABELED));
    }
}
