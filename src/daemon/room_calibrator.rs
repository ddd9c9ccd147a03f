//! The daemon's real calibrator: the room's detectors and [`crate::calibrate::calibrate`]
//! behind the daemon's [`Calibrator`] trait.

use crate::calibrate::{calibrate, CalibrateOptions, Detectors, FrameDetections};
use crate::capture::GreyFrame;
use crate::lidar::Point;
use crate::result::CalibrationResult;
use crate::target::Room;

use super::{CalibrationOutcome, Calibrator};

/// Detection and calibration for one room, with workspaces made once.
pub struct RoomCalibrator {
    room: Room,
    detectors: Detectors,
}

impl RoomCalibrator {
    /// The calibrator of `room`; fails when the room's pattern cannot be detected.
    pub fn new(room: Room) -> Result<Self, crate::detect::DetectError> {
        let detectors = Detectors::new(&room)?;
        Ok(RoomCalibrator { room, detectors })
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
        for (i, frame) in frames.iter().enumerate() {
            let camera = match self.detectors.detect_pixels(&frame.pixels) {
                Ok(boards) => boards,
                Err(e) => return CalibrationOutcome::Failed(format!("frame {i}: {e}")),
            };
            let lidar =
                sweeps.get(i).map_or(Vec::new(), |sweep| self.detectors.detect_cloud(sweep));
            detections.push(FrameDetections { camera, lidar });
        }
        let options = CalibrateOptions { current: current.cloned(), ..CalibrateOptions::default() };
        CalibrationOutcome::Done(Box::new(calibrate(&self.room, &detections, &options).result))
    }
}
