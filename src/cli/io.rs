//! Reading the command line's inputs (camera frames checked against the camera's size,
//! clouds decoded as the room's LiDAR) and writing its results.

use std::path::{Path, PathBuf};

use anyhow::Context;

use roomcal::detect::GreyImage;
use roomcal::lidar::pcd::MAX_POINTS;
use roomcal::lidar::Point;
use roomcal::result::CalibrationResult;
use roomcal::target::Room;

use super::{bad_input, Failure};

/// A frame read from disk and checked against the room's camera.
pub fn load_image(room: &Room, path: &Path) -> Result<GreyImage, Failure> {
    let size = (room.camera.width, room.camera.height);
    load_image_sized(path, size, "the room's camera")
}

/// A frame read from disk that must be `width × height` pixels, like `whose` camera.
pub fn load_image_sized(path: &Path, size: (u32, u32), whose: &str) -> Result<GreyImage, Failure> {
    check_image_sized(path, size, whose)?;
    roomcal::detect::load_grey(path).map_err(bad_input)
}

/// Refuses a frame whose header's size is not `width × height`, like `whose` camera;
/// nothing is decoded.
pub fn check_image_sized(
    path: &Path,
    (width, height): (u32, u32),
    whose: &str,
) -> Result<(), Failure> {
    let (got_width, got_height) = roomcal::detect::image_size(path).map_err(bad_input)?;
    if (got_width, got_height) != (width, height) {
        return Err(bad_input(anyhow::anyhow!(
            "image {}: {got_width}x{got_height} pixels, {whose} is {width}x{height}",
            path.display(),
        )));
    }
    Ok(())
}

/// A standing vehicle's frames averaged as they are read (each checked like
/// [`load_image_sized`]): one frame and the running sum are held whatever their number.
/// `None` without frames.
pub fn mean_image(
    paths: &[PathBuf],
    size: (u32, u32),
    whose: &str,
    mut on_read: impl FnMut(&Path),
) -> Result<Option<GreyImage>, Failure> {
    roomcal::capture::mean_image(
        paths,
        |path| {
            on_read(path);
            load_image_sized(path, size, whose)
        },
        |path, e| bad_input(anyhow::anyhow!("image {}: {e}", path.display())),
    )
}

/// The clouds of one run read from disk (as [`load_cloud`]), all held at once: refused once
/// they hold more than [`roomcal::lidar::pcd::MAX_POINTS`] points together, naming the file
/// that went over, so a run's clouds never hold more than one file's limit.
pub fn load_clouds(
    paths: &[PathBuf],
    mut load: impl FnMut(&Path) -> Result<Vec<Point>, Failure>,
) -> Result<Vec<Vec<Point>>, Failure> {
    let mut clouds = Vec::with_capacity(paths.len());
    let mut total = 0;
    for path in paths {
        let cloud = load(path)?;
        total += cloud.len();
        if total > MAX_POINTS {
            return Err(bad_input(anyhow::anyhow!(
                "cloud {}: the run's clouds hold {total} points with it, more than the \
                 {MAX_POINTS} points roomcal takes in one run",
                path.display()
            )));
        }
        clouds.push(cloud);
    }
    Ok(clouds)
}

/// A cloud read from disk: PCD, or a capture decoded as the room's LiDAR model with the
/// unit's angle file when given.
pub fn load_cloud(room: &Room, path: &Path, angles: Option<&Path>) -> Result<Vec<Point>, Failure> {
    let model = room.lidar.as_ref().and_then(|l| l.model);
    roomcal::lidar::read_cloud(path, model, angles).map_err(bad_input)
}

/// A result file's text (a pair's or a rig's): pretty JSON, one trailing newline.
pub fn result_json(result: &impl serde::Serialize) -> String {
    serde_json::to_string_pretty(result).expect("results serialise") + "\n"
}

/// Writes the result file and its OpenCV YAML beside it; returns both paths.
pub fn write_result(path: &Path, result: &CalibrationResult) -> Result<Vec<String>, Failure> {
    let yaml_path = path.with_extension("yaml");
    std::fs::write(path, result_json(result))
        .and_then(|()| std::fs::write(&yaml_path, roomcal::export::result_yaml(result)))
        .with_context(|| format!("writing {} and {}", path.display(), yaml_path.display()))
        .map_err(bad_input)?;
    Ok(vec![path.display().to_string(), yaml_path.display().to_string()])
}
