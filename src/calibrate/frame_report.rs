//! What `roomcal detect` reports for one frame: the boards in its image and its cloud, the
//! cloud's planes refused as boards, and in a surveyed room which surveyed board each
//! detection is — found as the calibration finds them, so the report shows what a run
//! would use.

use crate::detect::holes::RefusedBoard;
use crate::lidar::Point;
use crate::result::{BoardDetection, Detections};
use crate::target::Room;

use super::{
    calibrate_detecting, identify_detections, CalibrateOptions, CameraBoard, Detectors,
    FrameDetections, FrameIdentities, SolveFailure,
};

/// One frame's detections, the refused planes and the detections' identities.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameReport {
    pub frame: FrameDetections,
    /// The cloud's planes that were not taken as boards, and why (empty without a cloud).
    pub refused: Vec<RefusedBoard>,
    pub identities: Identification,
}

/// Which surveyed board each detection of a frame is.
#[derive(Clone, Debug, PartialEq)]
pub enum Identification {
    /// The room has no survey: there is nothing to name the boards by.
    NotSurveyed,
    /// Every detection named (`None` where one matches no surveyed board).
    Identified(FrameIdentities),
    /// The camera's boards could not be identified: why.
    Failed(SolveFailure),
    /// A surveyed room without an image: the LiDAR's boards are identified through the
    /// camera's room pose.
    NeedsImage,
}

/// Reports a frame from its image's boards (`camera`, `None` when no image was given) and
/// its sweep (`cloud`, when given). In a surveyed room with an image the LiDAR's boards are
/// found where the calibration finds them ([`calibrate_detecting`]: where the room expects
/// them, from the camera's room pose), elsewhere by global search.
pub fn detect_frame(
    room: &Room,
    detectors: &mut Detectors,
    camera: Option<Vec<CameraBoard>>,
    cloud: Option<&[Point]>,
) -> FrameReport {
    let image_given = camera.is_some();
    let mut frame = FrameDetections { camera: camera.unwrap_or_default(), lidar: Vec::new() };
    let refused = match cloud {
        Some(cloud) if room.survey.is_some() && image_given => {
            detect_as_calibrated(room, detectors, &mut frame, cloud)
        }
        Some(cloud) => {
            frame.lidar = detectors.detect_cloud(cloud);
            detectors.refused_in_cloud().to_vec()
        }
        None => Vec::new(),
    };
    let identities = match (&room.survey, image_given) {
        (Some(survey), true) => match identify_detections(room, survey, &frame) {
            Ok(ids) => Identification::Identified(ids),
            Err(reason) => Identification::Failed(reason),
        },
        (Some(_), false) => Identification::NeedsImage,
        (None, _) => Identification::NotSurveyed,
    };
    FrameReport { frame, refused, identities }
}

impl FrameReport {
    /// The identities when the boards were identified.
    pub fn identified(&self) -> Option<&FrameIdentities> {
        match &self.identities {
            Identification::Identified(ids) => Some(ids),
            _ => None,
        }
    }

    /// The detections file: the camera's boards, then the LiDAR's, each with its surveyed
    /// board when identified.
    pub fn detections(&self) -> Detections {
        let ids = self.identified();
        let mut out = Detections::default();
        for (i, board) in self.frame.camera.iter().enumerate() {
            let id = ids.and_then(|ids| ids.camera[i]);
            out.boards.push(BoardDetection {
                surveyed_board: id.map(|id| id.board as u32),
                half_turned: id.is_some_and(|id| id.half_turned),
                ..board.detection()
            });
        }
        for (l, board) in self.frame.lidar.iter().enumerate() {
            out.boards.push(BoardDetection {
                surveyed_board: ids.and_then(|ids| ids.lidar[l]).map(|k| k as u32),
                ..board.detection()
            });
        }
        out
    }
}

/// The LiDAR's boards of `frame` found in `cloud` by a calibration of the frame (its
/// result is not kept); returns the refused planes.
fn detect_as_calibrated(
    room: &Room,
    detectors: &mut Detectors,
    frame: &mut FrameDetections,
    cloud: &[Point],
) -> Vec<RefusedBoard> {
    let mut frames = [core::mem::take(frame)];
    let options = CalibrateOptions::default();
    let (_, refused) = calibrate_detecting(room, &mut frames, &[cloud], detectors, &options);
    let [done] = frames;
    *frame = done;
    refused.into_iter().next().unwrap_or_default()
}
