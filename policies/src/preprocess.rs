//! Observation preprocessing: what a policy family does to the env's observation before its
//! model sees it. The published numbers depend on reproducing this byte for byte (the training
//! images went through the same steps); a mismatch never raises, it only lowers the success rate.
//!
//! - [`image`]: 180° rotation, JPEG round trip, resize to 224 (Pillow's Lanczos or bilinear,
//!   openpi's pad-resize, OpenCV's `INTER_AREA`), OpenVLA's center crop. [`ImagePipeline`] chains them per family.
//! - [`proprio`]: the 8-dim LIBERO state, with the quaternion sign that robosuite's
//!   `robot0_eef_quat` has.
//!
//! ```
//! use libero_policies::preprocess::{ImagePipeline, RgbImage};
//! let frame = RgbImage::new(256, 256, vec![128; 256 * 256 * 3]).unwrap();
//! let x = ImagePipeline::OPENVLA.apply(&frame).unwrap();
//! assert_eq!((x.width, x.height), (224, 224));
//! assert_eq!(ImagePipeline::OPENVLA.describe(), "rot180,jpeg95,resize224:pil-lanczos,crop0.9:tf-bilinear");
//! ```
//!
//! Each step is tested against the reference Python (Pillow, numpy, robosuite) on the same images
//! by `tests/preprocess_parity.rs`.

pub mod image;
pub mod proprio;

pub use image::{Filter, RgbImage};
pub use proprio::{LIBERO_EEF_HEMISPHERE, QuatSign, libero_state, quat2axisangle};

/// Why an observation could not be preprocessed.
#[derive(Debug, thiserror::Error)]
pub enum PreprocessError {
    #[error("an RGB image of {width}x{height} needs {} bytes, got {bytes}", *width as usize * *height as usize * 3)]
    ImageSize { width: u32, height: u32, bytes: usize },
    #[error("JPEG round trip: {0}")]
    Jpeg(String),
    #[error("{0}")]
    Unsupported(String),
}

/// How an image is brought to the model's input size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resize {
    /// Keep the size.
    None,
    /// Stretch to `size × size` (OpenVLA: the frames are square already).
    Stretch { size: u32, filter: Filter },
    /// Fit inside `size × size` keeping the aspect ratio, black bars (openpi `resize_with_pad`).
    Pad { size: u32, filter: Filter },
    /// Stretch to `size × size` with OpenCV's `INTER_AREA` ([`image::resize_area_cv2`]).
    CvArea { size: u32 },
}

/// One policy family's image preprocessing, applied in this order: rotation, JPEG round trip,
/// resize, center crop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImagePipeline {
    /// `img[::-1, ::-1]`: LIBERO's cameras render upside down.
    pub rotate_180: bool,
    /// JPEG round trip at this quality (the RLDS datasets stored JPEG frames).
    pub jpeg_quality: Option<u8>,
    pub resize: Resize,
    /// OpenVLA's center crop of this area fraction, for checkpoints trained with random crops.
    pub center_crop: Option<f32>,
}

impl ImagePipeline {
    /// OpenVLA on LIBERO (`run_libero_eval.py` with `center_crop=True`, as the fine-tuned LIBERO
    /// checkpoints need): rot180, JPEG 95, Lanczos-3 antialiased resize to 224 (TensorFlow's in
    /// the reference, Pillow's here), center crop 0.9.
    pub const OPENVLA: ImagePipeline = ImagePipeline {
        rotate_180: true,
        jpeg_quality: Some(95),
        resize: Resize::Stretch { size: 224, filter: Filter::Lanczos },
        center_crop: Some(0.9),
    };
    /// OpenVLA-OFT: the same steps for each of its two images (agentview and wrist).
    pub const OPENVLA_OFT: ImagePipeline = ImagePipeline::OPENVLA;
    /// openpi (π0, π0.5) `examples/libero/main.py`: rot180, `resize_with_pad` 224 (Pillow
    /// bilinear), no JPEG, no crop.
    pub const OPENPI: ImagePipeline = ImagePipeline {
        rotate_180: true,
        jpeg_quality: None,
        resize: Resize::Pad { size: 224, filter: Filter::Bilinear },
        center_crop: None,
    };

    /// starVLA's LIBERO client at HEAD (`model2libero_interface.py`): rot180, Pillow bilinear
    /// stretch to 224 (when the frame is not 224 already), no JPEG, no crop.
    pub const STARVLA: ImagePipeline = ImagePipeline {
        rotate_180: true,
        jpeg_quality: None,
        resize: Resize::Stretch { size: 224, filter: Filter::Bilinear },
        center_crop: None,
    };
    /// VLA-JEPA's LIBERO client (ginwind/VLA-JEPA, the older starVLA): rot180, `cv2.resize`
    /// `INTER_AREA` to 224, no JPEG, no crop.
    pub const VLA_JEPA: ImagePipeline =
        ImagePipeline { rotate_180: true, jpeg_quality: None, resize: Resize::CvArea { size: 224 }, center_crop: None };

    pub fn apply(&self, img: &RgbImage) -> Result<RgbImage, PreprocessError> {
        img.check()?;
        let mut x = if self.rotate_180 { image::rotate_180(img) } else { img.clone() };
        if let Some(q) = self.jpeg_quality {
            x = image::jpeg_round_trip(&x, q)?;
        }
        x = match self.resize {
            Resize::None => x,
            Resize::Stretch { size, filter } => image::resize(&x, size, size, filter),
            Resize::Pad { size, filter } => image::resize_with_pad(&x, size, size, filter),
            Resize::CvArea { size } => image::resize_area_cv2(&x, size, size).ok_or_else(|| {
                PreprocessError::Unsupported(format!(
                    "INTER_AREA from {}x{} to {size}x{size}: only non-integer downscales are reproduced",
                    x.width, x.height
                ))
            })?,
        };
        if let Some(area) = self.center_crop {
            x = image::center_crop(&x, area);
        }
        Ok(x)
    }

    /// A short description for the run's provenance (policy identity).
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if self.rotate_180 {
            parts.push("rot180".to_string());
        }
        if let Some(q) = self.jpeg_quality {
            parts.push(format!("jpeg{q}"));
        }
        match self.resize {
            Resize::None => {}
            Resize::Stretch { size, filter } => parts.push(format!("resize{size}:{}", filter.name())),
            Resize::Pad { size, filter } => parts.push(format!("pad{size}:{}", filter.name())),
            Resize::CvArea { size } => parts.push(format!("resize{size}:cv2-area")),
        }
        if let Some(a) = self.center_crop {
            parts.push(format!("crop{a}:tf-bilinear"));
        }
        parts.join(",")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_describe_themselves() {
        assert_eq!(ImagePipeline::OPENPI.describe(), "rot180,pad224:pil-bilinear");
        assert_eq!(ImagePipeline::STARVLA.describe(), "rot180,resize224:pil-bilinear");
        assert_eq!(ImagePipeline::VLA_JEPA.describe(), "rot180,resize224:cv2-area");
        let none = ImagePipeline { rotate_180: false, jpeg_quality: None, resize: Resize::None, center_crop: None };
        assert_eq!(none.describe(), "");
    }

    #[test]
    fn a_bad_buffer_is_an_error() {
        let img = RgbImage { width: 4, height: 4, rgb: vec![0; 5] };
        let e = ImagePipeline::OPENPI.apply(&img).unwrap_err();
        assert_eq!(e.to_string(), "an RGB image of 4x4 needs 48 bytes, got 5");
    }

    #[test]
    fn openpi_pads_a_wide_frame() {
        let img = RgbImage::new(256, 128, vec![255; 256 * 128 * 3]).unwrap();
        let x = ImagePipeline::OPENPI.apply(&img).unwrap();
        assert_eq!((x.width, x.height), (224, 224));
        assert_eq!(&x.rgb[..3], &[0, 0, 0]);
        assert_eq!(&x.rgb[(112 * 224 + 112) * 3..][..3], &[255, 255, 255]);
    }
}
