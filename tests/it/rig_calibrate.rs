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

use crate::common::scratch::Scratch;

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

fn simulated(seed: u64) -> RigSimulation {
    simulated_rig(seed, roomcal::rig::load(&path("config/rig.toml")).unwrap())
}

/// The example rig with its bumper VLP-32C mounted level instead of pitched up: its dense
/// band then passes below the boards, and in seed 4's scene it places no board a camera
/// sees.
fn simulated_with_level_bumper(seed: u64) -> RigSimulation {
    let mut rig = roomcal::rig::load(&path("config/rig.toml")).unwrap();
    let bumper = rig.lidars.iter_mut().find(|l| l.name.as_str() == "bumper").unwrap();
    bumper.to_reference.rotation =
        roomcal::geometry::Mat3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    simulated_rig(seed, rig)
}

fn simulated_rig(seed: u64, rig: roomcal::rig::Rig) -> RigSimulation {
    let room = roomcal::room::load(&path("config/room.toml")).unwrap();
    let options = SimOptions {
        seed,
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
    SurveySpec {
        visits: 16,
        frame: heapless::String::try_from("sim").unwrap(),
        boards,
        planes,
        covariance: Default::default(),
    }
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

/// The boards are laid out for the 60° camera: in the 90° one they cover 25 % of the
/// image, below the default gate's 35 %; this room's [quality] asks for 20 %.
fn with_wide_coverage(sim: RigSimulation) -> RigSimulation {
    let mut room = sim.room.clone();
    room.quality.min_coverage = 0.2;
    RigSimulation { room, ..sim }
}

fn run(sim: &RigSimulation, room: &Room, free_boards: bool) -> RigCalibration {
    run_seeded(sim, room, free_boards, 7)
}

fn run_seeded(
    sim: &RigSimulation,
    room: &Room,
    free_boards: bool,
    noise_seed: u64,
) -> RigCalibration {
    let (cameras, lidars) = detections(sim, &mut Rng(noise_seed));
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
    let sim = simulated(2026);
    for (name, s) in &sim.truth.sensors {
        let placed =
            s.boards.iter().filter(|b| b.hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2);
        let seen = s.boards.iter().filter(|b| !b.corners_px.is_empty());
        println!("{name}: {} boards in view, {} LiDAR-placeable", seen.count(), placed.count());
    }
    let sim = with_wide_coverage(sim);
    let mut surveyed = sim.room.clone();
    surveyed.survey = Some(exact_survey(&sim.room_truth));
    let run_surveyed = run(&sim, &surveyed, false);
    check_against_truth("surveyed", &sim, &run_surveyed);
    assert!(run_surveyed.result.sensors["front"].camera_in_room.is_some());
    let run_free = run(&sim, &sim.room, true);
    check_against_truth("free", &sim, &run_free);
}

/// The rig of simulator seed `seed` and its room given the realistic survey the study
/// draws for that seed.
fn realistically_surveyed(sim: RigSimulation, seed: u64) -> (RigSimulation, Room) {
    let sim = with_wide_coverage(sim);
    let mut room = sim.room.clone();
    room.survey = Some(realistic_survey(&sim.room_truth, &mut Rng(1000 + seed)));
    (sim, room)
}

/// The survey 16 visits give, as the study assumes it: every board and plane off
/// the truth by 0.5 mm and 0.01° (1σ per axis, drawn), those σ declared.
fn realistic_survey(truth: &RoomTruth, rng: &mut Rng) -> SurveySpec {
    const SIGMA_M: f64 = 0.0005;
    const SIGMA_DEG: f64 = 0.01;
    let mut survey = exact_survey(truth);
    for b in survey.boards.iter_mut() {
        let pose = Extrinsic { rotation: b.rotation, translation: b.translation }.to_se3();
        let mut d = nalgebra::SVector::<f64, 6>::zeros();
        d.fixed_rows_mut::<3>(0).copy_from(&rng.vec3(SIGMA_DEG.to_radians()));
        d.fixed_rows_mut::<3>(3).copy_from(&rng.vec3(SIGMA_M));
        let off = Extrinsic::from_se3(&pose.perturb_left(&d));
        (b.rotation, b.translation) = (off.rotation, off.translation);
        (b.sigma_m, b.sigma_deg) = (SIGMA_M, SIGMA_DEG);
    }
    for p in survey.planes.iter_mut() {
        let turn = roomcal::geometry::se3::so3_exp(&rng.vec3(SIGMA_DEG.to_radians()));
        let normal = turn * Vec3::from(p.normal);
        p.normal = [normal.x, normal.y, normal.z];
        p.offset += SIGMA_M * rng.normal();
        (p.sigma_m, p.sigma_deg) = (SIGMA_M, SIGMA_DEG);
    }
    survey
}

/// Per quantity, every seed's (error, σ) in the quantity's unit; norms of 3-axis errors
/// are set against √3 × the worst-axis σ.
#[derive(Default)]
struct Tally(std::collections::BTreeMap<String, Vec<(f64, f64)>>);

impl Tally {
    fn add(&mut self, what: String, error: f64, sigma: f64) {
        self.0.entry(what).or_default().push((error, sigma));
    }

    /// Every camera's fx %, cx, cy px and every extrinsic's rotation ° and translation mm,
    /// of the sensors `verdicts` accepts (a rejected sensor claims no result).
    fn record(
        &mut self,
        sim: &RigSimulation,
        result: &roomcal::result::RigResult,
        verdicts: &roomcal::result::RigResult,
    ) {
        let accepted = |name: &str| verdicts.sensors[name].status == Status::Accepted;
        for camera in sim.rig.cameras.iter().filter(|c| accepted(c.name.as_str())) {
            let name = camera.name.as_str();
            let truth = sim.truth.sensors[name].camera.as_ref().unwrap();
            let (got, sigma) = (
                result.sensors[name].camera.as_ref().unwrap(),
                result.sensors[name].uncertainty.as_ref().unwrap(),
            );
            let pct = 100.0 / truth.fx;
            self.add(format!("{name} fx %"), (got.fx - truth.fx).abs() * pct, sigma.fx * pct);
            self.add(format!("{name} cx px"), (got.cx - truth.cx).abs(), sigma.cx);
            self.add(format!("{name} cy px"), (got.cy - truth.cy).abs(), sigma.cy);
        }
        let root3 = 3f64.sqrt();
        for ext in result.extrinsics.iter().filter(|e| accepted(e.from.as_str())) {
            let truth = &sim.truth.sensors[ext.from.as_str()].to_reference;
            let got = Extrinsic { rotation: ext.rotation, translation: ext.translation };
            let (deg, m) = truth.difference(&got);
            let to = &ext.to;
            self.add(format!("{}→{to} °", ext.from), deg, root3 * ext.sigma_rotation_deg);
            self.add(
                format!("{}→{to} mm", ext.from),
                m * 1e3,
                root3 * ext.sigma_translation_m * 1e3,
            );
        }
    }

    /// Per quantity: RMS error, largest error, RMS σ and RMS error/σ.
    fn summary(&self) -> Vec<(String, f64, f64, f64, f64)> {
        let rms = |v: &mut dyn Iterator<Item = f64>| {
            let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
            (s / n.max(1) as f64).sqrt()
        };
        self.0
            .iter()
            .map(|(what, v)| {
                let max = v.iter().map(|(e, _)| *e).fold(0.0, f64::max);
                (
                    what.clone(),
                    rms(&mut v.iter().map(|(e, _)| *e)),
                    max,
                    rms(&mut v.iter().map(|(_, s)| *s)),
                    rms(&mut v.iter().map(|(e, s)| e / s)),
                )
            })
            .collect()
    }
}

/// Ten vehicles (seeds 1–10: own intrinsics, mountings and parking) in a room surveyed as
/// 16 visits survey it (`realistic_survey`), each calibrated from one frame per sensor:
/// the joint solve's errors and σ against the pair runs' composition in the same runs.
/// The joint σ must be honest: RMS error/σ within 0.5–1.6 for every quantity. Of the
/// issue's targets (RMS over the vehicles) the intrinsics' are asserted (fx ≤ 0.1 %,
/// cx, cy ≤ 1.5 px); the extrinsics' (camera→camera ≤ 0.03° / 3 mm, LiDAR→camera
/// ≤ 0.05° / 4 mm) are printed met or missed — one frame in this survey does not hold them
/// all, and its σ say so. No extrinsic's RMS error may be more than 10 % above the
/// composition's (the pair runs, which leave the surveyed planes' points to
/// the joint solve: their LiDAR errors went from within a few per cent of the joint's to
/// 9–19 mm, top and bumper→front). Printed with `-- --nocapture`.
#[test]
fn ten_rigs_in_a_realistically_surveyed_room_joint_against_composition() {
    study(Some(&|truth, seed| realistic_survey(truth, &mut Rng(1000 + seed))), true);
}

/// The same ten vehicles in the room without a survey (free boards, one frame): the joint
/// solve ties the cameras through the boards both see and each LiDAR through the boards it
/// places, where the composition chains pair runs. Its σ must be honest (RMS error/σ within
/// 0.5–1.6) and no LiDAR→camera RMS error more than 10 % above the composition's; the
/// issue's targets are for a surveyed room and only printed here. Measured (seeds 1–10):
/// wide→front 0.023° / 3.70 mm RMS where the composition gave 0.36° / 23.8 mm; the bumper
/// VLP-32C places fewer than two boards a camera sees on five vehicles (four by one
/// board, seed 4 by none), which are rejected naming it, as their pair runs were.
#[test]
fn ten_rigs_with_free_boards_joint_against_composition() {
    study(None, true);
}

/// As above with the exact survey (σ 0), what the sensors alone allow
/// (`cargo test --test it rig_calibrate:: -- --ignored --nocapture`, 50 s): only the LiDAR→camera
/// errors against the composition's are asserted. The LiDAR σ are honest here too (RMS
/// error/σ 0.4–0.7 since the plane points are trimmed of what stands on the floor and
/// weighted along their beams; 1.3–2.8 before, from millimetres of bias those feet left).
#[test]
#[ignore]
fn ten_rigs_in_an_exactly_surveyed_room_joint_against_composition() {
    study(Some(&|truth, _| exact_survey(truth)), false);
}

/// A survey drawn for a room's truth and a seed.
type SurveyOf<'a> = &'a dyn Fn(&RoomTruth, u64) -> SurveySpec;

/// Calibrates seeds 1–10 in the room `survey` gives (`None`: free boards), prints joint
/// against composition and checks it (σ honesty only when `honest_sigma`).
fn study(survey: Option<SurveyOf<'_>>, honest_sigma: bool) {
    const SEEDS: u64 = 10;
    let (mut joint, mut composed) = (Tally::default(), Tally::default());
    let mut accepted = 0;
    for seed in 1..=SEEDS {
        let sim = with_wide_coverage(simulated(seed));
        let mut room = sim.room.clone();
        room.survey = survey.map(|survey| survey(&sim.room_truth, seed));
        let run = run_seeded(&sim, &room, survey.is_none(), seed);
        match run.result.pair.status {
            Status::Accepted => accepted += 1,
            Status::Rejected => println!("seed {seed}: rejected: {:?}", run.result.pair.reason),
        }
        joint.record(&sim, &run.result, &run.result);
        let composition = run.composition.as_ref().expect("a rig keeps its composition");
        composed.record(&sim, composition, &run.result);
    }
    println!("{accepted}/{SEEDS} accepted; per quantity over the vehicles: RMS error (largest), RMS σ, RMS error/σ");
    println!("{:<18} {:>36} {:>36}", "quantity", "joint", "composition");
    let composed = composed.summary();
    let mut failures = Vec::new();
    for ((what, e, max, s, ratio), (_, ce, cmax, cs, cratio)) in
        joint.summary().into_iter().zip(composed)
    {
        let unit = what.rsplit(' ').next().unwrap();
        let target = match unit {
            "%" => 0.1,
            "px" => 1.5,
            "°" if what.starts_with("wide") => 0.03,
            "°" => 0.05,
            "mm" if what.starts_with("wide") => 3.0,
            _ => 4.0,
        };
        let verdict = if e <= target { "met" } else { "MISSED" };
        println!(
            "{what:<18} {e:>8.4} ({max:.4}) σ {s:.4} {ratio:>4.2}   {ce:>8.4} ({cmax:.4}) σ {cs:.4} {cratio:>4.2}   target {target} {verdict}"
        );
        if what.contains('→') && e > 1.1 * ce {
            failures.push(format!(
                "{what}: joint RMS error {e:.4} more than 10 % above the composition's {ce:.4}"
            ));
        }
        if honest_sigma && !(0.5..=1.6).contains(&ratio) {
            failures.push(format!("{what}: joint RMS error/σ {ratio:.2}"));
        }
        if survey.is_some() && matches!(unit, "%" | "px") && e > target {
            failures.push(format!("{what}: joint RMS error {e:.4} above the target {target}"));
        }
    }
    if survey.is_some() && honest_sigma && accepted < SEEDS {
        failures.push(format!("{accepted}/{SEEDS} rigs accepted"));
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Over the binary, real detectors: `roomcal simulate --rig` (seed 3), the simulated room
/// given a survey (`realistic_survey` of its `room-truth.json`), `roomcal calibrate --rig`
/// on its images and sweeps. The result is the joint solve's: every camera has its pose in
/// the room, every extrinsic a σ and its error against `rig-truth.json` within 3√3σ.
#[test]
fn the_binary_calibrates_a_simulated_rig_in_a_surveyed_room() {
    let dir = Scratch::new("rig-surveyed");
    let roomcal = |args: &[&str]| {
        let out = std::process::Command::new(crate::common::BIN)
            .args(args)
            .output()
            .expect("roomcal runs");
        let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        (out.status.code().unwrap_or(-1), text(&out.stdout) + &text(&out.stderr))
    };
    let config = |f: &str| path("config").join(f).to_string_lossy().into_owned();
    let at = |f: &str| dir.join(f).to_string_lossy().into_owned();
    let (room, rig) = (config("room.toml"), config("rig.toml"));
    let d = at("");
    let args = ["simulate", "--room", &room, "--rig", &rig, "--out", &d, "--seed", "3"];
    let (code, text) = roomcal(&[&args[..], &["--supersample", "1"]].concat());
    assert_eq!(code, 0, "{text}");
    let mut surveyed = roomcal::room::load(&dir.join("room.toml")).unwrap();
    surveyed.quality.min_coverage = 0.2;
    let truth: RoomTruth =
        serde_json::from_str(&std::fs::read_to_string(dir.join("room-truth.json")).unwrap())
            .unwrap();
    surveyed.survey = Some(realistic_survey(&truth, &mut Rng(3)));
    std::fs::write(dir.join("surveyed.toml"), roomcal::room::to_toml(&surveyed)).unwrap();
    let (surveyed, out) = (at("surveyed.toml"), at("result.json"));
    let inputs = [
        format!("front={}", at("front.png")),
        format!("wide={}", at("wide.png")),
        format!("top={}", at("top.pcd")),
        format!("bumper={}", at("bumper.pcd")),
    ];
    let (code, text) = roomcal(&[
        "calibrate",
        "--room",
        &surveyed,
        "--rig",
        &rig,
        "--image",
        &inputs[0],
        "--image",
        &inputs[1],
        "--cloud",
        &inputs[2],
        "--cloud",
        &inputs[3],
        "--out",
        &out,
    ]);
    println!("{text}");
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let status = result["status"].as_str().unwrap();
    assert_eq!(code, if status == "accepted" { 0 } else { 3 }, "{text}");
    for camera in ["front", "wide"] {
        assert!(result["sensors"][camera]["camera_in_room"].is_object(), "{camera}");
    }
    let rig_truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("rig-truth.json")).unwrap())
            .unwrap();
    let extrinsics = result["extrinsics"].as_array().unwrap();
    assert_eq!(extrinsics.len(), 3, "{text}");
    let matrix = |v: &serde_json::Value| -> [[f64; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| v[i][j].as_f64().unwrap()))
    };
    let vector =
        |v: &serde_json::Value| -> [f64; 3] { std::array::from_fn(|i| v[i].as_f64().unwrap()) };
    let bound = 3.0 * 3f64.sqrt();
    for e in extrinsics {
        let from = e["from"].as_str().unwrap();
        let t = &rig_truth["sensors"][from]["to_reference"];
        let truth =
            Extrinsic { rotation: matrix(&t["rotation"]), translation: vector(&t["translation"]) };
        let got =
            Extrinsic { rotation: matrix(&e["rotation"]), translation: vector(&e["translation"]) };
        let (deg, m) = truth.difference(&got);
        let (s_deg, s_m) =
            (e["sigma_rotation_deg"].as_f64().unwrap(), e["sigma_translation_m"].as_f64().unwrap());
        println!(
            "binary, surveyed: {from} → front: {deg:.4}° (σ {s_deg:.4}) {:.2} mm (σ {:.2})",
            m * 1e3,
            s_m * 1e3
        );
        assert!(s_deg > 0.0 && s_m > 0.0, "{from}: σ must be positive");
        assert!(deg <= bound * s_deg && m <= bound * s_m, "{from}: outside 3σ");
    }
}

/// A board moved 3 cm since the survey (one the roof LiDAR places): the pair runs and the
/// joint solve leave it out (named in the log; the LiDARs' measurements of it too), and
/// the rig still matches the truth. The room's gate asks for 5 of its 6 boards here, and
/// 15 % coverage (the wide camera's corners cover 19 % without that board).
#[test]
fn a_board_moved_since_the_survey_is_left_out_of_the_joint_solve() {
    let sim = with_wide_coverage(simulated(2026));
    let placed =
        |b: &roomcal::sim::BoardTruth| b.hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2;
    let moved = sim.truth.sensors["top"].boards.iter().position(placed).unwrap();
    let mut survey = realistic_survey(&sim.room_truth, &mut Rng(5));
    survey.boards[moved].translation[0] += 0.03;
    let mut room = sim.room.clone();
    room.survey = Some(survey);
    (room.quality.min_boards, room.quality.min_coverage) = (Some(5), 0.15);
    let run = run(&sim, &room, false);
    println!("board {moved} moved by 30 mm");
    check_against_truth("moved board", &sim, &run);
}

/// In a surveyed room each sensor's verdict is the joint solve's: seed 4's bumper VLP-32C,
/// mounted level, places no board a camera sees (the pair runs' composition rejects it), yet
/// the room's planes and the survey tie it to the room, and it is accepted within its σ. A
/// LiDAR that sees nothing of the room, or a camera that sees too few boards, is named and
/// rejects the rig.
#[test]
fn in_a_surveyed_room_each_sensor_is_judged_by_the_joint_solve() {
    let (sim, room) = realistically_surveyed(simulated_with_level_bumper(4), 4);
    let (cameras, lidars) = detections(&sim, &mut Rng(4));
    let bumper = sim.rig.lidars.iter().position(|l| l.name.as_str() == "bumper").unwrap();
    assert!(lidars[bumper].is_empty(), "seed 4's bumper places no board");
    let options = CalibrateOptions::default();
    let calibrate = |cameras: &[Vec<CameraBoard>], clouds: &[&[roomcal::lidar::Point]]| {
        let inputs: Vec<LidarInput<'_>> =
            lidars.iter().zip(clouds).map(|(b, c)| LidarInput { boards: b, cloud: c }).collect();
        calibrate_rig(&room, &sim.rig, cameras, &inputs, &options)
    };
    let clouds: Vec<&[roomcal::lidar::Point]> = sim.clouds.iter().map(|c| c.as_slice()).collect();
    let run = calibrate(&cameras, &clouds);
    let composed = &run.composition.as_ref().expect("a rig keeps its composition").sensors;
    assert_eq!(composed["bumper"].status, Status::Rejected, "the pair runs alone fail it");
    let entry = &run.result.sensors["bumper"];
    assert_eq!((entry.status, &entry.reason), (Status::Accepted, &None), "{entry:?}");
    assert_eq!(run.result.pair.status, Status::Accepted, "{:?}", run.result.pair.reason);
    check_against_truth("bumper by the room", &sim, &run);

    let mut blind = clouds.clone();
    blind[bumper] = &[];
    let run = calibrate(&cameras, &blind).result;
    let reason = rejected_naming(&run, "bumper blind", "lidar `bumper`");
    assert_eq!(run.sensors["top"].status, Status::Accepted, "{reason}");

    let wide = sim.rig.cameras.iter().position(|c| c.name.as_str() == "wide").unwrap();
    let mut few = cameras.clone();
    few[wide].truncate(2);
    let run = calibrate(&few, &clouds).result;
    let reason = rejected_naming(&run, "wide camera with 2 boards", "camera `wide`");
    assert_eq!(run.sensors["front"].status, Status::Accepted, "{reason}");
}

/// Without a survey nothing ties seed 4's level bumper (it places no board a camera sees): the
/// free-board joint solve leaves it out and rejects it by name, gives it no extrinsic, and
/// still solves the others (every given extrinsic within 3σ of the truth).
#[test]
fn with_free_boards_a_sensor_nothing_ties_is_named() {
    let sim = with_wide_coverage(simulated_with_level_bumper(4));
    let run = run_seeded(&sim, &sim.room, true, 4);
    let reason = rejected_naming(&run.result, "free boards, seed 4", "lidar `bumper`");
    assert!(reason.contains("shares no board with the first camera"), "{reason}");
    for name in ["front", "wide", "top"] {
        assert_eq!(run.result.sensors[name].status, Status::Accepted, "{name}: {reason}");
    }
    assert!(run.result.extrinsics.iter().all(|e| e.from != "bumper"));
    let bound = 3.0 * 3f64.sqrt();
    for ext in &run.result.extrinsics {
        let truth = &sim.truth.sensors[ext.from.as_str()].to_reference;
        let got = Extrinsic { rotation: ext.rotation, translation: ext.translation };
        let (deg, m) = truth.difference(&got);
        assert!(deg <= bound * ext.sigma_rotation_deg, "{}: {deg}°", ext.from);
        assert!(m <= bound * ext.sigma_translation_m, "{}: {m} m", ext.from);
    }
}

/// Asserts the rig was rejected with a reason containing `needle`, prints it (`what`) and
/// returns it.
fn rejected_naming(run: &roomcal::result::RigResult, what: &str, needle: &str) -> String {
    let reason = run.pair.reason.clone().unwrap_or_default();
    println!("{what}: {reason}");
    assert_eq!(run.pair.status, Status::Rejected, "{what}");
    assert!(reason.contains(needle), "{what}: {reason}");
    reason
}

/// The change limits against the rig in force: the same rig again passes; with the rig in
/// force holding the bumper mounted 15 cm elsewhere, or the wide camera's focal length 5 %
/// longer, that sensor is named and the rig rejected, the others still accepted.
#[test]
fn a_rig_that_moved_from_the_rig_in_force_is_rejected_naming_the_sensor() {
    let (sim, room) = realistically_surveyed(simulated(2026), 2026);
    let (cameras, lidars) = detections(&sim, &mut Rng(7));
    let inputs: Vec<LidarInput<'_>> =
        lidars.iter().zip(&sim.clouds).map(|(b, c)| LidarInput { boards: b, cloud: c }).collect();
    let against = |current: Option<roomcal::result::RigResult>| {
        let options = CalibrateOptions { current_rig: current, ..CalibrateOptions::default() };
        calibrate_rig(&room, &sim.rig, &cameras, &inputs, &options).result
    };
    let in_force = against(None);
    assert_eq!(in_force.pair.status, Status::Accepted, "{:?}", in_force.pair.reason);
    let again = against(Some(in_force.clone()));
    assert_eq!(again.pair.status, Status::Accepted, "{:?}", again.pair.reason);

    let mut moved = in_force.clone();
    moved.extrinsics.iter_mut().find(|e| e.from == "bumper").unwrap().translation[2] += 0.15;
    let run = against(Some(moved));
    let what = "bumper moved in the rig in force";
    let reason = rejected_naming(&run, what, "lidar `bumper`: mounting moved");
    assert_eq!(run.sensors["bumper"].status, Status::Rejected);
    assert_eq!(run.sensors["top"].status, Status::Accepted, "{reason}");

    let mut longer = in_force.clone();
    longer.sensors.get_mut("wide").unwrap().camera.as_mut().unwrap().fx *= 1.05;
    let run = against(Some(longer));
    let what = "wide camera's focal length in force 5 % longer";
    let reason = rejected_naming(&run, what, "camera `wide`: focal length moved");
    assert_eq!(run.sensors["front"].status, Status::Accepted, "{reason}");
}

/// In a surveyed room each LiDAR of a rig is searched where the room expects its boards
/// (`expected_in_rig_lidars`: the first camera's boards identified against the survey, the
/// LiDAR's nominal mounting): over seeds 1–6 it places as many boards as the global search,
/// every one within 2 cm of a true board (hole centroid), the first camera's corners the
/// truth with noise.
#[test]
fn a_rigs_lidars_are_found_where_the_surveyed_room_expects_their_boards() {
    use roomcal::calibrate::{expected_in_rig_lidars, Detectors};
    let (mut expected_total, mut global_total) = (0, 0);
    for seed in 1..=6 {
        let sim = with_wide_coverage(simulated(seed));
        let mut room = sim.room.clone();
        room.survey = Some(exact_survey(&sim.room_truth));
        let (cameras, _) = detections(&sim, &mut Rng(seed));
        let expected = expected_in_rig_lidars(&room, &sim.rig, &cameras[0], false)
            .expect("the first camera's boards identify the room");
        assert!(expected_in_rig_lidars(&room, &sim.rig, &cameras[0], true).is_none());
        for (l, lidar) in sim.rig.lidars.iter().enumerate() {
            let mut detectors = Detectors::new(&sim.rig.pair_room(&room, 0, Some(l))).unwrap();
            let cloud = &sim.clouds[l];
            let global = detectors.detect_cloud(cloud);
            let at = detectors.detect_where_expected(cloud, Some(&expected.lidars[l]));
            let truth = &sim.truth.sensors[lidar.name.as_str()].boards;
            for board in &at {
                let centre = board.holes.iter().sum::<Vec3>() / board.holes.len() as f64;
                let off = truth
                    .iter()
                    .map(|b| {
                        let holes = b.holes_lidar.iter().map(|h| Vec3::from(*h));
                        (holes.sum::<Vec3>() / b.holes_lidar.len() as f64 - centre).norm()
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    off < 0.02,
                    "seed {seed} {}: a board {off:.3} m from any true one",
                    lidar.name
                );
            }
            println!(
                "seed {seed} {}: {} where expected, {} by global search",
                lidar.name,
                at.len(),
                global.len()
            );
            assert!(at.len() >= global.len(), "seed {seed} {}: fewer where expected", lidar.name);
            (expected_total, global_total) =
                (expected_total + at.len(), global_total + global.len());
        }
    }
    println!("boards placed: {expected_total} where expected, {global_total} by global search");
}

/// The first camera's start that found the LiDARs' boards (`RigExpectation::first_start`),
/// given to the rig's calibration, is the start it would make: the same result, value for
/// value.
#[test]
fn a_rig_given_its_first_cameras_start_is_the_rig_that_makes_it() {
    use roomcal::calibrate::expected_in_rig_lidars;
    let sim = with_wide_coverage(simulated(2026));
    let mut room = sim.room.clone();
    room.survey = Some(exact_survey(&sim.room_truth));
    let (cameras, lidars) = detections(&sim, &mut Rng(5));
    let inputs: Vec<LidarInput<'_>> =
        lidars.iter().zip(&sim.clouds).map(|(b, c)| LidarInput { boards: b, cloud: c }).collect();
    let expected = expected_in_rig_lidars(&room, &sim.rig, &cameras[0], false).unwrap();
    let given = CalibrateOptions {
        corner_start: Some(expected.first_start),
        ..CalibrateOptions::default()
    };
    let made = calibrate_rig(&room, &sim.rig, &cameras, &inputs, &CalibrateOptions::default());
    let with_start = calibrate_rig(&room, &sim.rig, &cameras, &inputs, &given);
    assert_eq!(with_start.result, made.result);
    assert_eq!(made.result.pair.status, roomcal::result::Status::Accepted);
}

/// A run given its camera's start from the corners (`CalibrateOptions::corner_start`, as a
/// rig's pair runs share it) is the run that makes the start itself, value for value; a
/// start of other detections (another pose count) is not used.
#[test]
fn a_run_given_its_corner_start_is_the_run_that_makes_it() {
    use roomcal::calibrate::{calibrate_with_clouds, corner_start, FrameDetections};
    let sim = with_wide_coverage(simulated(2026));
    let mut room = sim.rig.pair_room(&sim.room, 0, Some(0));
    room.survey = Some(exact_survey(&sim.room_truth));
    let (cameras, lidars) = detections(&sim, &mut Rng(5));
    let frames = [FrameDetections { camera: cameras[0].clone(), lidar: lidars[0].clone() }];
    let clouds: [&[roomcal::lidar::Point]; 1] = [&sim.clouds[0]];
    let start = corner_start(&room, &frames).unwrap();
    for free_boards in [false, true] {
        let plain = CalibrateOptions { free_boards, ..CalibrateOptions::default() };
        let given = CalibrateOptions { corner_start: Some(start.clone()), ..plain.clone() };
        let made = calibrate_with_clouds(&room, &frames, &clouds, &plain);
        let shared = calibrate_with_clouds(&room, &frames, &clouds, &given);
        assert_eq!(made.result, shared.result, "free boards {free_boards}");
        assert_eq!(made.result.status, Status::Accepted, "{:?}", made.result.reason);
    }
    let mut other = start.clone();
    other.poses.pop();
    other.camera.fx *= 1.5;
    let given = CalibrateOptions { corner_start: Some(other), ..CalibrateOptions::default() };
    let plain = calibrate_with_clouds(&room, &frames, &clouds, &CalibrateOptions::default());
    assert_eq!(calibrate_with_clouds(&room, &frames, &clouds, &given).result, plain.result);
}
