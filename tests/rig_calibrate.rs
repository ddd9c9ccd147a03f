//! A rig's calibration against the simulator's truth (`calibrate::rig::calibrate_rig`):
//! the example rig `config/rig.toml` (a 60° and a 90° camera, a roof Pandar64 and a
//! bumper VLP-32C) parked once in the design's six-board room, `simulate_rig` rendering
//! every camera and casting every sweep; in the room surveyed exactly (the survey built
//! from the simulator's room truth) and with free boards.
//!
//! Detections are the truth with noise (corners 0.025 px, holes 3 mm) and the rendered
//! sweeps (2 cm ranges), so the test measures the composition, not the detectors. Every
//! error must lie within 3σ of the run's own σ (3√3σ for 3-axis norms against
//! worst-axis σ); the figures are printed (`-- --nocapture`).

use std::path::Path;

use roomcal::calibrate::rig::{calibrate_rig, LidarInput, RigCalibration};
use roomcal::calibrate::{plane_points, CalibrateOptions, CameraBoard, LidarBoard};
use roomcal::geometry::{Vec2, Vec3};
use roomcal::result::{Extrinsic, Status};
use roomcal::sim::rig::{simulate_rig, RigSimulation};
use roomcal::sim::visits::RoomTruth;
use roomcal::sim::{ImageNoise, SimOptions};
use roomcal::target::{Room, SurveySpec, SurveyedBoard, SurveyedPlane};

const CORNER_NOISE_PX: f64 = 0.025;
const HOLE_NOISE_M: f64 = 0.003;

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (2.0 * std::f64::consts::PI * self.uniform()).cos()
    }
    fn vec3(&mut self, s: f64) -> Vec3 {
        Vec3::new(self.normal(), self.normal(), self.normal()) * s
    }
}

fn path(relative: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(relative)
}

fn simulated() -> RigSimulation {
    let room = roomcal::room::load(&path("config/room.toml")).unwrap();
    let rig = roomcal::rig::load(&path("config/rig.toml")).unwrap();
    let options = SimOptions {
        seed: 2026,
        range_noise_m: 0.02,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    simulate_rig(&room, &rig, &options).unwrap()
}

/// The exact survey of the simulated room (σ 0, floored by the solve at 1 µm / 1 µrad).
fn exact_survey(truth: &RoomTruth) -> SurveySpec {
    let boards = truth
        .boards
        .iter()
        .map(|b| SurveyedBoard {
            rotation: b.rotation,
            translation: b.translation,
            sigma_m: 0.0,
            sigma_deg: 0.0,
        })
        .collect();
    let planes = truth
        .planes
        .iter()
        .map(|p| SurveyedPlane {
            name: heapless::String::try_from(p.name.as_str()).unwrap(),
            normal: p.normal,
            offset: p.offset,
            sigma_m: 0.0,
            sigma_deg: 0.0,
        })
        .collect();
    SurveySpec { visits: 16, frame: heapless::String::try_from("sim").unwrap(), boards, planes }
}

/// Per camera its complete, unoccluded boards; per LiDAR the boards with at least two
/// holes crossed by two scan lines, with their face points.
fn detections(sim: &RigSimulation, rng: &mut Rng) -> (Vec<Vec<CameraBoard>>, Vec<Vec<LidarBoard>>) {
    let cameras = sim
        .rig
        .cameras
        .iter()
        .map(|c| {
            let truth = &sim.truth.sensors[c.name.as_str()];
            truth
                .boards
                .iter()
                .filter(|b| !b.corners_px.is_empty() && b.occluded_corners == 0)
                .map(|b| CameraBoard {
                    corners: b
                        .corners_px
                        .iter()
                        .map(|p| {
                            Vec2::new(
                                p[0] + CORNER_NOISE_PX * rng.normal(),
                                p[1] + CORNER_NOISE_PX * rng.normal(),
                            )
                        })
                        .collect(),
                    sigma_px: CORNER_NOISE_PX,
                })
                .collect()
        })
        .collect();
    let lidars = sim
        .rig
        .lidars
        .iter()
        .zip(&sim.clouds)
        .map(|(l, cloud)| {
            let truth = &sim.truth.sensors[l.name.as_str()];
            truth
                .boards
                .iter()
                .filter(|b| b.hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2)
                .map(|b| {
                    let points =
                        cloud.iter().map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64));
                    let plane =
                        plane_points(&sim.room.board, &b.board_to_camera.to_se3(), 0.06, points);
                    LidarBoard {
                        holes: b
                            .holes_lidar
                            .iter()
                            .map(|h| Vec3::from(*h) + rng.vec3(HOLE_NOISE_M))
                            .collect(),
                        sigma_m: HOLE_NOISE_M,
                        plane,
                    }
                })
                .collect()
        })
        .collect();
    (cameras, lidars)
}

fn run(sim: &RigSimulation, room: &Room, free_boards: bool) -> RigCalibration {
    let (cameras, lidars) = detections(sim, &mut Rng(7));
    let inputs: Vec<LidarInput<'_>> =
        lidars.iter().zip(&sim.clouds).map(|(b, c)| LidarInput { boards: b, cloud: c }).collect();
    let options = CalibrateOptions { free_boards, ..CalibrateOptions::default() };
    calibrate_rig(room, &sim.rig, &cameras, &inputs, &options)
}

/// Prints and checks every camera's intrinsics and every extrinsic against the truth.
fn check_against_truth(what: &str, sim: &RigSimulation, run: &RigCalibration) {
    let result = &run.result;
    for (name, sensor) in &result.sensors {
        println!("{what} {name}: {:?} {}", sensor.status, sensor.reason.as_deref().unwrap_or(""));
    }
    let bound = 3.0 * 3f64.sqrt();
    for camera in &sim.rig.cameras {
        let name = camera.name.as_str();
        let truth = sim.truth.sensors[name].camera.as_ref().unwrap();
        let got = result.sensors[name].camera.as_ref().unwrap();
        let sigma = result.sensors[name].uncertainty.as_ref().unwrap();
        let fx_pct = (got.fx - truth.fx).abs() / truth.fx * 100.0;
        let (cx, cy) = ((got.cx - truth.cx).abs(), (got.cy - truth.cy).abs());
        println!(
            "{what} camera {name:<6} fx {fx_pct:.4} % (σ {:.4}) cx {cx:.2} px (σ {:.2}) cy {cy:.2} px (σ {:.2})",
            sigma.fx / got.fx * 100.0,
            sigma.cx,
            sigma.cy
        );
        assert!(fx_pct <= 3.0 * sigma.fx / got.fx * 100.0, "{what} {name}: fx outside 3σ");
        assert!(cx <= 3.0 * sigma.cx && cy <= 3.0 * sigma.cy, "{what} {name}: cx/cy outside 3σ");
    }
    let first = sim.rig.cameras[0].name.as_str();
    assert_eq!(result.extrinsics.len(), sim.rig.cameras.len() - 1 + sim.rig.lidars.len());
    for ext in &result.extrinsics {
        assert_eq!(ext.to, first);
        let truth = &sim.truth.sensors[ext.from.as_str()].to_reference;
        let got = Extrinsic { rotation: ext.rotation, translation: ext.translation };
        let (deg, m) = truth.difference(&got);
        println!(
            "{what} {:>6} → {first}: rotation {deg:.4}° (σ {:.4}) translation {:.2} mm (σ {:.2})",
            ext.from,
            ext.sigma_rotation_deg,
            m * 1000.0,
            ext.sigma_translation_m * 1000.0
        );
        assert!(deg <= bound * ext.sigma_rotation_deg, "{what} {}: rotation outside 3σ", ext.from);
        assert!(
            m <= bound * ext.sigma_translation_m,
            "{what} {}: translation outside 3σ",
            ext.from
        );
    }
    assert_eq!(result.pair.status, Status::Accepted, "{what}: {:?}", result.pair.reason);
}

#[test]
fn a_rig_in_the_surveyed_room_and_with_free_boards_matches_the_truth() {
    let sim = simulated();
    for (name, s) in &sim.truth.sensors {
        let placed =
            s.boards.iter().filter(|b| b.hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2);
        let seen = s.boards.iter().filter(|b| !b.corners_px.is_empty());
        println!("{name}: {} boards in view, {} LiDAR-placeable", seen.count(), placed.count());
    }
    // The boards are laid out for the 60° camera: in the 90° one they cover 25 % of the
    // image, below the default gate's 35 %; this room's [quality] asks for 20 %.
    let mut room = sim.room.clone();
    room.quality.min_coverage = 0.2;
    let sim = RigSimulation { room, ..sim };
    let mut surveyed = sim.room.clone();
    surveyed.survey = Some(exact_survey(&sim.room_truth));
    let run_surveyed = run(&sim, &surveyed, false);
    check_against_truth("surveyed", &sim, &run_surveyed);
    assert!(run_surveyed.result.sensors["front"].camera_in_room.is_some());
    let run_free = run(&sim, &sim.room, true);
    check_against_truth("free", &sim, &run_free);
}
