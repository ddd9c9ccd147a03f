//! `roomcal overlay`: a cloud drawn onto an image through a calibration (a result file),
//! to check any calibration by eye.

use std::path::PathBuf;

use anyhow::{anyhow, Context};
use clap::Args;

use super::io::load_image_sized;
use super::{bad_input, Failure};

#[derive(Args)]
pub struct OverlayArgs {
    /// The calibration: a result file (`roomcal calibrate --out`, or the store's current.json).
    #[arg(long)]
    calibration: PathBuf,
    /// The camera frame (PNG or JPEG), of the calibration's image size.
    #[arg(long)]
    image: PathBuf,
    /// The LiDAR cloud (PCD).
    #[arg(long)]
    cloud: PathBuf,
    /// Where to write the overlay (PNG).
    #[arg(long)]
    out: PathBuf,
}

/// `roomcal overlay`: writes the overlay picture.
pub fn run(args: OverlayArgs) -> Result<(), Failure> {
    let result = roomcal::result::load(&args.calibration).map_err(bad_input)?;
    let Some(extrinsic) = &result.lidar_to_camera else {
        return Err(bad_input(anyhow!(
            "{}: the calibration has no LiDAR→camera extrinsic",
            args.calibration.display()
        )));
    };
    let camera = result.camera.to_camera();
    let size = (camera.width, camera.height);
    let image = load_image_sized(&args.image, size, "the calibration's camera")?;
    let cloud = roomcal::lidar::read_cloud(&args.cloud, None, None).map_err(bad_input)?;
    roomcal::report::overlay(&image.data, &camera, Some(&extrinsic.to_se3()), &[&cloud], &[])
        .save(&args.out)
        .with_context(|| format!("writing the overlay {}", args.out.display()))
        .map_err(bad_input)?;
    say!("overlay of {} points written to {}", cloud.len(), args.out.display());
    Ok(())
}
