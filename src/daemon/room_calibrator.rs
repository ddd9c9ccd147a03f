//! The daemon's real calibrator: the room's detectors and [`crate::calibrate::calibrate`]
//! behind the daemon's [`Calibrator`] trait, drawing each run's report picture(s) when asked;
//! for a rig ([`RoomCalibrator::with_rig`]) every camera's detectors and
//! [`crate::calibrate::rig::calibrate_rig`].

use std::path::PathBuf;

use crate::calibrate::rig::{calibrate_rig, LidarInput};
use crate::calibrate::{
    calibrate_detecting, expected_in_rig_lidars, CalibrateOptions, Detectors, FrameDetections,
    LidarAngles, LidarBoard, RigDetectors,
};
use crate::capture::GreyFrame;
use crate::detect::holes::RefusedBoard;
use crate::detect::DetectError;
use crate::lidar::Point;
use crate::result::{CalibrationResult, RigResult};
use crate::rig::Rig;
use crate::target::Room;

use super::config::{Config, LidarSource};
use super::{CalibrationOutcome, Calibrator};

/// Detection and calibration for one room, with workspaces made once.
pub struct RoomCalibrator {
    room: Room,
    /// One camera's for the one-pair vehicle, every camera's for a rig; the first camera's
    /// count the trigger's boards and run the one-pair calibration.
    detectors: RigDetectors,
    report: Option<PathBuf>,
    rig: Option<Rig>,
    lidar_angles: LidarAngles,
}

/// The beam angles of `config`'s LiDARs (the rig's, or the one-pair vehicle's): the
/// model's nominal table when any LiDAR's packets, live or a replayed capture, are
/// decoded without the unit's angle file ([`LidarAngles`]).
pub fn lidar_angles(config: &Config) -> LidarAngles {
    let sources: Vec<(&LidarSource, Option<&PathBuf>)> = match &config.rig {
        Some(rig) => rig.lidars.iter().map(|l| (&l.source, l.calibration.as_ref())).collect(),
        None => vec![(&config.lidar, config.lidar_calibration.as_ref())],
    };
    let of = |(source, file): (&LidarSource, Option<&PathBuf>)| {
        let decoded_here = match source {
            LidarSource::Udp(_) => true,
            LidarSource::Replay(path) => crate::lidar::is_packet_capture(path),
        };
        LidarAngles::of(decoded_here, file.is_some())
    };
    sources.into_iter().map(of).find(|a| *a == LidarAngles::Nominal).unwrap_or_default()
}

impl RoomCalibrator {
    /// The calibrator of `room`; fails when the room's pattern cannot be detected.
    pub fn new(room: Room) -> Result<Self, crate::detect::DetectError> {
        let detectors = RigDetectors { cameras: vec![Detectors::new(&room)?] };
        Ok(RoomCalibrator {
            room,
            detectors,
            report: None,
            rig: None,
            lidar_angles: LidarAngles::Unit,
        })
    }

    /// Calibrates `rig` instead of the room's one pair: its cameras' detectors made now.
    pub fn with_rig(mut self, rig: Rig) -> Result<Self, crate::detect::DetectError> {
        self.detectors = RigDetectors::new(&self.room, &rig)?;
        self.rig = Some(rig);
        Ok(self)
    }

    /// Where the LiDARs' beam angles come from ([`lidar_angles`] of the daemon's
    /// configuration): a run placing a LiDAR by faces alone on a nominal table is refused.
    pub fn with_lidar_angles(mut self, angles: LidarAngles) -> Self {
        self.lidar_angles = angles;
        self
    }

    /// Also writes every run's report picture (PNG, as `roomcal calibrate --report` draws
    /// it) to `path`, atomically, e.g. the store's `last-run.png`; a rig's run writes one
    /// per camera, the camera's name before the extension (`last-run-front.png`: its frame
    /// with every LiDAR drawn through the solved rig, [`crate::report::ReportInput::rig`]).
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
        let input = crate::report::ReportInput::calibration(&frame.pixels, &clouds, run, refused);
        write_picture(path, &crate::report::report(&input));
    }
}

/// Writes a report picture as PNG to `path`, atomically; a failure is logged, never fatal.
fn write_picture(path: &std::path::Path, picture: &image::RgbImage) {
    let mut png = std::io::Cursor::new(Vec::new());
    let written = picture
        .write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| e.to_string())
        .and_then(|()| crate::store::write_atomic(path, png.get_ref()).map_err(|e| e.to_string()));
    if let Err(e) = written {
        tracing::warn!(
            "{}: the run's report picture was not written ({e}); the calibration is unaffected",
            path.display()
        );
    }
}

impl Calibrator for RoomCalibrator {
    fn count_boards(&mut self, camera: usize, frame: &GreyFrame) -> Result<usize, DetectError> {
        let Some(detectors) = self.detectors.cameras.get_mut(camera) else { return Ok(0) };
        detectors.detect_pixels(&frame.pixels).map(|boards| boards.len())
    }

    /// A rig's run, or the one-pair room's; a rig's gate compares with the record in force
    /// only when that is a rig's too.
    fn calibrate(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        current: Option<&RigResult>,
    ) -> CalibrationOutcome {
        match self.rig.is_some() {
            true => self.calibrate_rig(frames, sweeps, current.filter(|r| r.is_rig())),
            false => self.calibrate_pair(frames, sweeps, current.map(|r| &r.pair)),
        }
    }
}

impl RoomCalibrator {
    fn calibrate_pair(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        current: Option<&CalibrationResult>,
    ) -> CalibrationOutcome {
        let mut detections = Vec::with_capacity(frames.len());
        for (i, frame) in frames.iter().enumerate() {
            let camera = match self.detectors.first().detect_pixels(&frame.pixels) {
                Ok(boards) => boards,
                Err(e) => return CalibrationOutcome::Failed(format!("frame {i}: {e}")),
            };
            detections.push(FrameDetections { camera, lidar: Vec::new() });
        }
        let options = CalibrateOptions {
            current: current.cloned(),
            lidar_angles: self.lidar_angles,
            ..CalibrateOptions::default()
        };
        // The run finds the LiDAR's boards (in a surveyed room where the room expects them),
        // and the sweeps' points on the surveyed planes enter the solve.
        let clouds: Vec<&[Point]> = sweeps.iter().map(Vec::as_slice).collect();
        let (run, refused) = calibrate_detecting(
            &self.room,
            &mut detections,
            &clouds,
            self.detectors.first(),
            &options,
        );
        // The detectors' workspaces are not held under the report and between visits.
        self.detectors.first().release_chessboard();
        self.detectors.first().release_holes();
        let refused_first = refused.into_iter().next().unwrap_or_default();
        if let Some(first) = frames.first() {
            self.write_report(first, sweeps.first(), &run, &refused_first);
        }
        CalibrationOutcome::Done(Box::new(run.result.into()))
    }

    fn calibrate_rig(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        current: Option<&RigResult>,
    ) -> CalibrationOutcome {
        let (Some(rig), detectors) = (&self.rig, &mut self.detectors) else {
            return CalibrationOutcome::Failed("the daemon was not configured with a rig".into());
        };
        let mut cameras = Vec::with_capacity(frames.len());
        for ((frame, d), camera) in frames.iter().zip(&mut detectors.cameras).zip(&rig.cameras) {
            match d.detect_pixels(&frame.pixels) {
                Ok(boards) => cameras.push(boards),
                Err(e) => {
                    return CalibrationOutcome::Failed(format!("camera `{}`: {e}", camera.name))
                }
            }
        }
        // Each detector's workspaces are freed once its sensors are detected: they are not
        // held under the next detections, the solve, the report and between visits (the
        // run's peak memory, docs/design-notes.md "Daemon and memory").
        detectors.cameras.iter_mut().for_each(Detectors::release_chessboard);
        // In a surveyed room each LiDAR is searched where the room expects its boards.
        let first = cameras.first().map_or(&[][..], Vec::as_slice);
        let expected = expected_in_rig_lidars(&self.room, rig, first, false);
        let boards: Vec<Vec<LidarBoard>> = (sweeps.iter().enumerate())
            .map(|(l, s)| {
                let at = expected.as_ref().and_then(|e| e.lidars.get(l)).map(Vec::as_slice);
                detectors.detect_lidar(s, at)
            })
            .collect();
        detectors.first().release_holes();
        let lidars: Vec<LidarInput<'_>> =
            boards.iter().zip(sweeps).map(|(boards, cloud)| LidarInput { boards, cloud }).collect();
        let options = CalibrateOptions {
            current_rig: current.cloned(),
            corner_start: expected.map(|e| e.first_start),
            lidar_angles: self.lidar_angles,
            ..CalibrateOptions::default()
        };
        let run = calibrate_rig(&self.room, rig, &cameras, &lidars, &options);
        if let Some(path) = &self.report {
            let sweeps: Vec<&[Point]> = sweeps.iter().map(Vec::as_slice).collect();
            let lidar_boards: Vec<&[LidarBoard]> = boards.iter().map(Vec::as_slice).collect();
            for (c, (camera, frame)) in rig.cameras.iter().zip(frames).enumerate() {
                let marks = crate::report::RigMarks {
                    corners: cameras.get(c).map_or(&[][..], Vec::as_slice),
                    sweeps: &sweeps,
                    lidar_boards: &lidar_boards,
                };
                let input =
                    crate::report::ReportInput::rig(rig, &run.result, c, &frame.pixels, &marks);
                if let Some(input) = input {
                    let picture = crate::report::report(&input);
                    write_picture(&crate::report::camera_path(path, &camera.name), &picture);
                }
            }
        }
        CalibrationOutcome::Done(Box::new(run.result))
    }
}
