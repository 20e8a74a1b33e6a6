//! The pinhole camera, matching Mitsuba 3's `perspective` sensor with a `look_at`
//! transform: frame, field of view per `fov_axis`, pixel-centre rays in f64.
//!
//! `forward = normalize(target - origin)`, `left = normalize(up × forward)`,
//! `true_up = forward × left`; image x grows toward `-left`, image y downward (row 0 is the
//! top row). One ray per pixel through its centre `(i + 0.5, j + 0.5)`. Intrinsics come in
//! both pixel conventions: [`Camera::k_matrix`] (centres at `i + 0.5`) and
//! [`Camera::k_matrix_opencv`] (centres at integers).

use glam::{DMat4, DVec2, DVec3, DVec4};
use serde::{Deserialize, Serialize};

pub mod lens;
pub mod model;

use lens::Lens;

/// How a camera maps a pixel to a ray and a world point to a pixel: the one place a
/// projection is defined. [`Camera::pixel_ray`] and [`Camera::project`] dispatch on it; a
/// new model is one variant here plus its tests.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Mitsuba's `perspective` sensor with a `look_at` transform: the pinhole every scene
    /// file describes today (the tiles' fast path assumes it).
    Perspective,
    /// Mitsuba's `orthographic` sensor: parallel rays along `forward`, from the image
    /// plane through the camera origin; pixel centres at `i + 0.5` as the pinhole.
    Orthographic {
        /// Half the image width in world units (`ortho_width / 2`).
        half_width: f64,
        /// Half the image height in world units (`half_width / aspect`).
        half_height: f64,
    },
    /// A lens model in the camera's OpenCV axes (x right, y down, z forward), see [`lens`].
    Lens(Lens),
}

/// One pixel's primary ray: `origin + t · dir` for `t` in `[tmin, tmax]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelRay {
    /// Where the ray starts, world units (the camera centre, except orthographic).
    pub origin: DVec3,
    /// Unit direction, world axes.
    pub dir: DVec3,
    /// Smallest ray parameter counted (the near clip along this ray).
    pub tmin: f64,
    /// Largest ray parameter counted (the far clip along this ray); below `tmin` for a
    /// pixel that has no ray (never so for a validated camera).
    pub tmax: f64,
    /// Whether `depth` along this ray is camera-space z (`t · dir·forward`); if not, it is
    /// the Euclidean distance `t` (equirectangular, fisheye rays at or beyond 90°).
    pub planar_depth: bool,
}

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
    /// How pixels map to rays: [`Projection::Perspective`] (the pinhole of `fov_deg`) or
    /// another model, whose `fov_deg` is unused.
    pub projection: Projection,
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
    /// How pixels map to rays (the spec's); for [`Projection::Perspective`] the pinhole
    /// `tan_half_x`, `tan_half_y` and the offset helpers below describe it.
    pub projection: Projection,
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
            projection: spec.projection,
        }
    }

    /// This camera's frame with another projection (validated by the caller: a lens by
    /// [`Lens::validate`], an orthographic extent finite and positive).
    pub fn with_projection(self, projection: Projection) -> Self {
        Camera { projection, ..self }
    }

    /// Whether the camera is the pinhole the screen tiles and the per-column/per-row
    /// offset helpers assume.
    pub fn is_pinhole(&self) -> bool {
        self.projection == Projection::Perspective
    }

    /// Camera-space coordinates of world point `p`, OpenCV axes (x right, y down, z
    /// forward).
    pub fn to_camera_opencv(&self, p: DVec3) -> DVec3 {
        let v = p - self.origin;
        DVec3::new(-v.dot(self.left), -v.dot(self.true_up), v.dot(self.forward))
    }

    /// World direction of camera-space (OpenCV axes) direction `v`.
    pub fn from_camera_opencv(&self, v: DVec3) -> DVec3 {
        -self.left * v.x - self.true_up * v.y + self.forward * v.z
    }

    /// Pixel `(i, j)`'s ray under this camera's projection. For the perspective pinhole it
    /// is the render's pixel ray bit for bit ([`Camera::dir_and_length`] at the column and
    /// row offsets, [`Camera::clip_range`]).
    pub fn pixel_ray(&self, i: u32, j: u32) -> PixelRay {
        let (near, far) = (self.spec.near_clip, self.spec.far_clip);
        match self.projection {
            Projection::Perspective => {
                let (dir, len) = self.dir_and_length(self.column_offset(i), self.row_offset(j));
                let (tmin, tmax) = self.clip_range(len);
                PixelRay {
                    origin: self.origin,
                    dir,
                    tmin,
                    tmax,
                    planar_depth: true,
                }
            }
            Projection::Orthographic {
                half_width,
                half_height,
            } => {
                let x = ((i as f64 + 0.5) / self.spec.width as f64 * 2.0 - 1.0) * half_width;
                let y = (1.0 - (j as f64 + 0.5) / self.spec.height as f64 * 2.0) * half_height;
                PixelRay {
                    origin: self.origin - self.left * x + self.true_up * y,
                    dir: self.forward,
                    tmin: near,
                    tmax: far,
                    planar_depth: true,
                }
            }
            Projection::Lens(lens) => match lens.unproject(i, j) {
                Ok(v) => {
                    let planar = lens.planar_depth(v);
                    // Planar clips become ray parameters through 1/cos θ; where depth is
                    // Euclidean the clips bound the distance itself.
                    let scale = if planar { 1.0 / v.z } else { 1.0 };
                    PixelRay {
                        origin: self.origin,
                        dir: self.from_camera_opencv(v).normalize(),
                        tmin: near * scale,
                        tmax: far * scale,
                        planar_depth: planar,
                    }
                }
                Err(_) => PixelRay {
                    origin: self.origin,
                    dir: self.forward,
                    tmin: 1.0,
                    tmax: 0.0,
                    planar_depth: true,
                },
            },
        }
    }

    /// The continuous pixel coordinates world point `p` projects to, in the projection's
    /// own pixel convention (centres at `i + 0.5` for perspective, orthographic and
    /// equirectangular; at integers for the OpenCV models); `None` where it has no image
    /// (behind a pinhole, at the camera centre).
    pub fn project(&self, p: DVec3) -> Option<DVec2> {
        let c = self.to_camera_opencv(p);
        let (w, h) = (self.spec.width as f64, self.spec.height as f64);
        match self.projection {
            Projection::Perspective => (c.z > 0.0).then(|| {
                DVec2::new(
                    (c.x / c.z / self.tan_half_x + 1.0) * 0.5 * w,
                    (c.y / c.z / self.tan_half_y + 1.0) * 0.5 * h,
                )
            }),
            Projection::Orthographic {
                half_width,
                half_height,
            } => Some(DVec2::new(
                (c.x / half_width + 1.0) * 0.5 * w,
                (c.y / half_height + 1.0) * 0.5 * h,
            )),
            Projection::Lens(lens) => lens.project(c),
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
