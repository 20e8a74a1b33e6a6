//! The pinhole camera, matching Mitsuba 3's `perspective` sensor with a `look_at`
//! transform: frame, field of view per `fov_axis`, pixel-centre rays in f64.
//!
//! `forward = normalize(target - origin)`, `left = normalize(up × forward)`,
//! `true_up = forward × left`; image x grows toward `-left`, image y downward (row 0 is the
//! top row). One ray per pixel through its centre `(i + 0.5, j + 0.5)`. Intrinsics come in
//! both pixel conventions: [`Camera::k_matrix`] (centres at `i + 0.5`) and
//! [`Camera::k_matrix_opencv`] (centres at integers).

use glam::{DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};

/// Which image extent `fov_deg` spans, as Mitsuba's `fov_axis`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FovAxis {
    /// `fov_deg` spans the image width (the default).
    #[default]
    X,
    /// `fov_deg` spans the image height.
    Y,
    /// `fov_deg` spans the image diagonal.
    Diagonal,
    /// `fov_deg` spans the smaller of width and height.
    Smaller,
    /// `fov_deg` spans the larger of width and height.
    Larger,
}

impl FovAxis {
    /// The name as scene files and Mitsuba spell it (`x`, `y`, `diagonal`, `smaller`, `larger`).
    pub fn name(self) -> &'static str {
        match self {
            FovAxis::X => "x",
            FovAxis::Y => "y",
            FovAxis::Diagonal => "diagonal",
            FovAxis::Smaller => "smaller",
            FovAxis::Larger => "larger",
        }
    }
}

/// A validated camera (see `scene` for the checks).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    /// Camera centre, world units.
    pub origin: DVec3,
    /// Point looked at, world units (differs from `origin`).
    pub target: DVec3,
    /// Up hint, non-zero, not parallel to `target - origin`; need not be unit or orthogonal.
    pub up: DVec3,
    /// Field of view in degrees, in (0, 180), spanning the extent `fov_axis` names.
    pub fov_deg: f64,
    /// Which image extent `fov_deg` spans.
    pub fov_axis: FovAxis,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Near clip: smallest camera-space z counted, > 0 (world units).
    pub near_clip: f64,
    /// Far clip: largest camera-space z counted, > `near_clip` (world units).
    pub far_clip: f64,
}

/// The camera frame and projection, derived once from a [`CameraSpec`].
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    /// The spec this camera was built from.
    pub spec: CameraSpec,
    /// Camera centre, world units (`spec.origin`).
    pub origin: DVec3,
    /// Unit view direction, `normalize(target - origin)`.
    pub forward: DVec3,
    /// `normalize(up × forward)`; image x grows toward `-left`.
    pub left: DVec3,
    /// `forward × left`; image y grows toward `-true_up`.
    pub true_up: DVec3,
    /// Half width of the image plane at unit distance: `tan` of half the x field of view.
    pub tan_half_x: f64,
    /// Half height of the image plane at unit distance: `tan_half_x / (width / height)`.
    pub tan_half_y: f64,
}

impl Camera {
    /// Build the frame and the half extents from a validated spec (as Mitsuba converts
    /// every `fov_axis` to an x field of view).
    pub fn new(spec: CameraSpec) -> Self {
        let forward = (spec.target - spec.origin).normalize();
        let left = spec.up.cross(forward).normalize();
        let true_up = forward.cross(left);
        let aspect = spec.width as f64 / spec.height as f64;
        let t = (spec.fov_deg.to_radians() / 2.0).tan();
        // Half-width at unit distance; Mitsuba converts every fov_axis to an x fov.
        let tan_half_x = match spec.fov_axis {
            FovAxis::X => t,
            FovAxis::Y => t * aspect,
            FovAxis::Diagonal => t * aspect / (1.0 + aspect * aspect).sqrt(),
            FovAxis::Smaller if aspect > 1.0 => t * aspect,
            FovAxis::Smaller => t,
            FovAxis::Larger if aspect > 1.0 => t,
            FovAxis::Larger => t * aspect,
        };
        Camera {
            spec,
            origin: spec.origin,
            forward,
            left,
            true_up,
            tan_half_x,
            tan_half_y: tan_half_x / aspect,
        }
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.spec.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.spec.height
    }

    /// Image-plane offset of column `i` at unit distance, toward `-left`:
    /// `((i + 0.5) / W · 2 - 1) · tan(fov_x / 2)`, in f64.
    #[inline]
    pub fn column_offset(&self, i: u32) -> f64 {
        (((i as f64 + 0.5) / self.spec.width as f64) * 2.0 - 1.0) * self.tan_half_x
    }

    /// Image-plane offset of row `j` toward `true_up` (row 0 is the top row).
    #[inline]
    pub fn row_offset(&self, j: u32) -> f64 {
        (1.0 - ((j as f64 + 0.5) / self.spec.height as f64) * 2.0) * self.tan_half_y
    }

    /// Unit direction through the image-plane offsets `(x, y)` of `column_offset` and
    /// `row_offset`: callers that sweep many pixels precompute those once per column/row.
    #[inline(always)]
    pub fn dir_from_offsets(&self, x: f64, y: f64) -> DVec3 {
        (self.forward - self.left * x + self.true_up * y).normalize()
    }

    /// [`Camera::dir_from_offsets`] and the length of the unnormalised direction, which is
    /// `1 / cos θ` (θ from `forward`): the same `d`, bit for bit.
    #[inline(always)]
    pub fn dir_and_length(&self, x: f64, y: f64) -> (DVec3, f64) {
        let v = self.pixel_vector(x, y);
        let len = v.length();
        (v * (1.0 / len), len)
    }

    /// The unnormalised pixel direction through the image-plane offsets `(x, y)`: its
    /// camera-space z is 1, so along it the ray parameter is planar depth. Rays cast along
    /// it from `origin` with `t` in `[near_clip, far_clip]` are a render's pixel rays, bit
    /// for bit, once normalised as [`Camera::dir_and_length`] does.
    #[inline(always)]
    pub fn pixel_vector(&self, x: f64, y: f64) -> DVec3 {
        self.forward - self.left * x + self.true_up * y
    }

    /// The ray parameters of camera-space z = near and far clip along a pixel ray whose
    /// unnormalised direction has length `len` (= 1/cos θ: the image plane is at unit
    /// distance along `forward`), with no further division.
    #[inline(always)]
    pub fn clip_range(&self, len: f64) -> (f64, f64) {
        (self.spec.near_clip * len, self.spec.far_clip * len)
    }

    /// Unit direction of the ray through the centre of pixel (i, j), all in f64:
    /// `(i + 0.5) / W` and `(j + 0.5) / H`. Row 0 is the top row.
    #[inline]
    pub fn ray_dir(&self, i: u32, j: u32) -> DVec3 {
        self.dir_from_offsets(self.column_offset(i), self.row_offset(j))
    }

    /// Focal lengths in pixels.
    pub fn focal_px(&self) -> (f64, f64) {
        (
            self.spec.width as f64 / 2.0 / self.tan_half_x,
            self.spec.height as f64 / 2.0 / self.tan_half_y,
        )
    }

    /// Intrinsics in pixels, principal point at `(W/2, H/2)`: the convention where pixel
    /// `(i, j)` has its centre at `(i + 0.5, j + 0.5)` (this camera's rays, Mitsuba,
    /// nerfstudio with its default `pixel_offset = 0.5`).
    pub fn k_matrix(&self) -> [[f64; 3]; 3] {
        let (fx, fy) = self.focal_px();
        let (cx, cy) = (self.spec.width as f64 / 2.0, self.spec.height as f64 / 2.0);
        [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
    }

    /// Intrinsics in pixels, principal point at `(W/2 - 0.5, H/2 - 0.5)`: the convention
    /// where pixel `(i, j)` has its centre at the integer point `(i, j)` (OpenCV, Open3D,
    /// COLMAP). The same rays as [`Camera::k_matrix`], with pixel coordinates shifted by
    /// half a pixel; using `k_matrix` there puts back-projected points half a pixel off.
    pub fn k_matrix_opencv(&self) -> [[f64; 3]; 3] {
        let mut k = self.k_matrix();
        k[0][2] -= 0.5;
        k[1][2] -= 0.5;
        k
    }

    /// Camera-to-world, OpenCV axes (x right, y down, z forward).
    pub fn world_from_camera_opencv(&self) -> DMat4 {
        DMat4::from_cols(
            (-self.left).extend(0.0),
            (-self.true_up).extend(0.0),
            self.forward.extend(0.0),
            DVec4::new(self.origin.x, self.origin.y, self.origin.z, 1.0),
        )
    }

    /// Camera-to-world, OpenGL axes (x right, y up, z backward).
    pub fn world_from_camera_opengl(&self) -> DMat4 {
        DMat4::from_cols(
            (-self.left).extend(0.0),
            self.true_up.extend(0.0),
            (-self.forward).extend(0.0),
            DVec4::new(self.origin.x, self.origin.y, self.origin.z, 1.0),
        )
    }
}

/// Row-major nested arrays, the layout JSON readers expect.
pub fn rows(m: DMat4) -> [[f64; 4]; 4] {
    let t = m.transpose().to_cols_array_2d();
    [t[0], t[1], t[2], t[3]]
}
