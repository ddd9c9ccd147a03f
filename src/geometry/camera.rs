//! Camera models. API contract; bodies are filled by the geometry work.

use super::{Vec2, Vec3};

/// Most intrinsic parameters any model has: fx fy cx cy + 5 distortion coefficients.
pub const MAX_INTRINSICS: usize = 9;

/// The projection model of a camera (the room file's `camera.model`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum CameraModel {
    /// Pinhole with OpenCV's radial-tangential distortion k1 k2 p1 p2 k3.
    #[serde(rename = "pinhole-radtan")]
    PinholeRadtan,
    /// Kannala–Brandt k1..k4 as OpenCV's fisheye module defines it.
    #[serde(rename = "fisheye")]
    Fisheye,
}

/// A calibrated camera: model, image size, intrinsics and distortion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub model: CameraModel,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1 k2 p1 p2 k3 (pinhole-radtan) or k1 k2 k3 k4 and a zero (fisheye).
    pub distortion: [f64; 5],
}

impl Camera {
    /// Pixel of a point in the camera frame; `None` behind the camera or outside the
    /// model's valid domain.
    pub fn project(&self, p: &Vec3) -> Option<Vec2> {
        let _ = p;
        todo!("geometry core")
    }

    /// Unit ray (camera frame) seen by a pixel; `None` where the model does not invert.
    pub fn unproject(&self, px: &Vec2) -> Option<Vec3> {
        let _ = px;
        todo!("geometry core")
    }
}
