//! The pinhole camera model shared by every reader, the renderer and the reconstruction.
//! Pixel centres sit at integer coordinates (pixel (u, v) covers u-0.5..u+0.5), which is the
//! convention of 7-Scenes, TUM, ScanNet and Replica intrinsics.

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics of a depth image (colour is resampled to the depth image by readers).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// Builds intrinsics, rejecting non-finite or non-positive focal lengths and empty images.
    pub fn new(width: u32, height: u32, fx: f32, fy: f32, cx: f32, cy: f32) -> crate::Result<Self> {
        let ok = width > 0
            && height > 0
            && fx.is_finite()
            && fy.is_finite()
            && fx > 0.0
            && fy > 0.0
            && cx.is_finite()
            && cy.is_finite();
        if !ok {
            return Err(crate::DataError::InvalidArgument(format!(
                "intrinsics {width}x{height} fx={fx} fy={fy} cx={cx} cy={cy} are not a valid camera"
            )));
        }
        Ok(Self { width, height, fx, fy, cx, cy })
    }

    /// The same camera at another resolution (focal lengths and centre scaled; the centre
    /// follows the pixel-centre convention).
    pub fn scaled(&self, width: u32, height: u32) -> Self {
        let sx = width as f32 / self.width as f32;
        let sy = height as f32 / self.height as f32;
        Self {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
        }
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Projects a point in the camera frame to pixel coordinates (no bounds check;
    /// meaningless for `p_camera.z <= 0`).
    #[inline]
    pub fn project(&self, p_camera: Vec3) -> Vec2 {
        Vec2::new(self.fx * p_camera.x / p_camera.z + self.cx, self.fy * p_camera.y / p_camera.z + self.cy)
    }

    /// Back-projects pixel `(u, v)` at depth `z` (metres along the optical axis) into the
    /// camera frame.
    #[inline]
    pub fn unproject(&self, u: f32, v: f32, z: f32) -> Vec3 {
        Vec3::new((u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_inverts_unproject() {
        let k = Intrinsics::new(640, 480, 585.0, 586.0, 320.0, 240.0).expect("valid");
        let p = k.unproject(100.5, 33.25, 2.5);
        let uv = k.project(p);
        assert!((uv.x - 100.5).abs() < 1e-4 && (uv.y - 33.25).abs() < 1e-4);
        assert!(Intrinsics::new(0, 480, 1.0, 1.0, 0.0, 0.0).is_err());
        assert!(Intrinsics::new(640, 480, f32::NAN, 1.0, 0.0, 0.0).is_err());
    }

    #[test]
    fn scaling_keeps_the_field_of_view() {
        let k = Intrinsics::new(1296, 968, 1170.0, 1170.0, 647.5, 483.5).expect("valid");
        let s = k.scaled(648, 484);
        let a = k.unproject(0.0 - 0.5, 0.0 - 0.5, 1.0);
        let b = s.unproject(0.0 - 0.5, 0.0 - 0.5, 1.0);
        assert!((a - b).length() < 1e-5);
    }
}
