//! The daemon's real calibrator: the room's detectors and [`crate::calibrate::calibrate`]
//! behind the daemon's [`Calibrator`] trait, drawing each run's report picture when asked.

use std::path::PathBuf;

use crate::calibrate::{calibrate_with_clouds, CalibrateOptions, Detectors, FrameDetections};
use crate::capture::GreyFrame;
use crate::detect::holes::RefusedBoard;
use crate::lidar::Point;
use crate::result::CalibrationResult;
use crate::target::Room;

use super::{CalibrationOutcome, Calibrator};

/// Detection and calibration for one room, with workspaces made once.
pub struct RoomCalibrator {
    room: Room,
    detectors: Detectors,
    report: Option<PathBuf>,
}

impl RoomCalibrator {
    /// The calibrator of `room`; fails when the room's pattern cannot be detected.
    pub fn new(room: Room) -> Result<Self, crate::detect::DetectError> {
        let detectors = Detectors::new(&room)?;
        Ok(RoomCalibrator { room, detectors, report: None })
    }

    /// Also writes every run's report picture (PNG, as `roomcal calibrate --report` draws
    /// it) to `path`, atomically, e.g. the store's `last-run.png`.
    pub fn with_report(mut self, path: PathBuf) -> Self {
        self.report = Some(path);
        self
    }

    /// Draws and writes the report of the first frame; a failure is logged, never fatal
    /// (the picture is for people, the calibration does not depend on it).
    fn write_report(
        &self,
        frame: &GreyFrame,
        sweep: Option<&Vec<Point>>,
        run: &crate::calibrate::Calibration,
        refused: &[RefusedBoard],
    ) {
        let Some(path) = &self.report else { return };
        let clouds: Vec<&[Point]> = sweep.map(|s| s.as_slice()).into_iter().collect();
        let picture = crate::report::calibration_report(&frame.pixels, &clouds, run, refused);
        let mut png = std::io::Cursor::new(Vec::new());
        let written = picture
            .write_to(&mut png, image::ImageFormat::Png)
            .map_err(|e| e.to_string())
            .and_then(|()| {
                crate::store::write_atomic(path, png.get_ref()).map_err(|e| e.to_string())
            });
        if let Err(e) = written {
            tracing::warn!(
                "{}: the run's report picture was not written ({e}); the calibration is unaffected",
                path.display()
            );
        }
    }
}

impl Calibrator for RoomCalibrator {
    fn count_boards(&mut self, frame: &GreyFrame) -> usize {
        self.detectors.detect_pixels(&frame.pixels).map_or(0, |boards| boards.len())
    }

    fn calibrate(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        current: Option<&CalibrationResult>,
    ) -> CalibrationOutcome {
        let mut detections = Vec::with_capacity(frames.len());
        let mut refused_first = Vec::new();
        for (i, frame) in frames.iter().enumerate() {
            let camera = match self.detectors.detect_pixels(&frame.pixels) {
                Ok(boards) => boards,
                Err(e) => return CalibrationOutcome::Failed(format!("frame {i}: {e}")),
            };
            let lidar =
                sweeps.get(i).map_or(Vec::new(), |sweep| self.detectors.detect_cloud(sweep));
            if i == 0 && self.report.is_some() {
                refused_first = self.detectors.refused_in_cloud().to_vec();
            }
            detections.push(FrameDetections { camera, lidar });
        }
        let options = CalibrateOptions { current: current.cloned(), ..CalibrateOptions::default() };
        // In a surveyed room the sweeps' points on the surveyed planes enter the solve.
        let clouds: Vec<&[Point]> = sweeps.iter().map(Vec::as_slice).collect();
        let run = calibrate_with_clouds(&self.room, &detections, &clouds, &options);
        if let Some(first) = frames.first() {
            self.write_report(first, sweeps.first(), &run, &refused_first);
        }
        CalibrationOutcome::Done(Box::new(run.result))
    }
}
