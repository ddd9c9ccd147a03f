//! An in-memory [`Backend`] for tests, examples and bench tools: fixed calibration
//! records, a calibration "run" that finishes after a set number of polls, rollback
//! through the generations.

use super::uds::{one_pair_extrinsic, one_pair_intrinsics};
use super::uds::{
    Backend, CameraModel, DaemonState, ExtrinsicRecord, IntrinsicsRecord, Outcome, QualityRecord,
    Refusal, SensorKind, SensorTable, StateRecord, MAX_SENSORS,
};

/// A backend with a calibration in force (or none), answering from memory.
#[derive(Clone, Debug)]
pub struct FakeBackend {
    /// State and the calibration in force.
    pub state: StateRecord,
    pub intrinsics: Option<IntrinsicsRecord>,
    pub extrinsic: Option<ExtrinsicRecord>,
    pub quality: Option<QualityRecord>,
    /// `calibration_finished` polls a run takes.
    pub run_polls: u32,
    /// Result state of the next runs (Accepted, Rejected or Error).
    pub run_result: DaemonState,
    /// Refuse to start runs.
    pub refuse_start: bool,
    /// Polls left in the run in progress.
    running: Option<u32>,
    /// Runs started so far.
    pub runs_started: u32,
    /// A rig's sensors and their records; `None`: the one-pair rig of [`Backend`]'s
    /// defaults (camera 0 = `intrinsics`, LiDAR 1 = `extrinsic`).
    pub rig: Option<FakeRig>,
}

/// The sensors of a rig and, by sensor index, their intrinsics and extrinsics.
#[derive(Clone, Debug, Default)]
pub struct FakeRig {
    pub sensors: SensorTable,
    pub intrinsics: heapless::Vec<Option<IntrinsicsRecord>, MAX_SENSORS>,
    pub extrinsics: heapless::Vec<Option<ExtrinsicRecord>, MAX_SENSORS>,
}

impl FakeBackend {
    /// Generation 7 of a plausible 1920×1200 camera and LiDAR mounting.
    pub fn calibrated() -> Self {
        let mut distortion = heapless::Vec::new();
        for d in [-0.25f32, 0.0625, 0.001, -0.0005, 0.0] {
            let _ = distortion.push(d);
        }
        FakeBackend {
            state: StateRecord { state: DaemonState::Idle, generation: 7, time: 1_700_000_000 },
            intrinsics: Some(IntrinsicsRecord {
                model: CameraModel::PinholeRadtan,
                fx: 1000.0,
                fy: 1000.5,
                cx: 960.0,
                cy: 600.0,
                distortion,
            }),
            extrinsic: Some(ExtrinsicRecord {
                rotation: [0.5, -0.5, 0.5, -0.5],
                translation: [0.05, 0.42, -0.28],
            }),
            quality: Some(QualityRecord { corner_rms_px: 0.125, hole_rms_px: 0.75, boards: 6 }),
            run_polls: 3,
            run_result: DaemonState::Accepted,
            refuse_start: false,
            running: None,
            runs_started: 0,
            rig: None,
        }
    }

    /// [`FakeBackend::calibrated`] on a four-sensor rig: cameras `front` (the one-pair
    /// records) and `wide` (fx 600), LiDARs `top` (the one-pair extrinsic) and `bumper`
    /// (translation z −0.9 m, not yet calibrated: `None`).
    pub fn rig() -> Self {
        let one = Self::calibrated();
        let mut rig = FakeRig::default();
        let wide = one.intrinsics.clone().map(|k| IntrinsicsRecord { fx: 600.0, fy: 600.25, ..k });
        let side = ExtrinsicRecord {
            rotation: [0.9659258, 0.0, 0.258819, 0.0],
            translation: [0.4, 0.0, 0.1],
        };
        let sensors = [
            (SensorKind::Camera, "front", one.intrinsics.clone(), Some(ExtrinsicRecord::IDENTITY)),
            (SensorKind::Camera, "wide", wide, Some(side)),
            (SensorKind::Lidar, "top", None, one.extrinsic),
            (SensorKind::Lidar, "bumper", None, None),
        ];
        for (kind, name, intrinsics, extrinsic) in sensors {
            // Four sensors with short valid names fit the table.
            let _ = rig.sensors.push(kind, name);
            let _ = rig.intrinsics.push(intrinsics);
            let _ = rig.extrinsics.push(extrinsic);
        }
        FakeBackend { rig: Some(rig), ..one }
    }

    /// No calibration in force yet (generation 0, every record `None`).
    pub fn empty() -> Self {
        FakeBackend {
            state: StateRecord { state: DaemonState::Idle, generation: 0, time: 0 },
            intrinsics: None,
            extrinsic: None,
            quality: None,
            ..Self::calibrated()
        }
    }
}

impl Backend for FakeBackend {
    fn state(&self) -> StateRecord {
        self.state
    }

    fn intrinsics(&self) -> Option<IntrinsicsRecord> {
        self.intrinsics.clone()
    }

    fn extrinsic(&self) -> Option<ExtrinsicRecord> {
        self.extrinsic
    }

    fn quality(&self) -> Option<QualityRecord> {
        self.quality
    }

    fn sensors(&self) -> SensorTable {
        match &self.rig {
            Some(rig) => rig.sensors.clone(),
            None => SensorTable::one_pair(true),
        }
    }

    fn sensor_intrinsics(&self, index: u8) -> Option<IntrinsicsRecord> {
        match &self.rig {
            Some(rig) => rig.intrinsics.get(usize::from(index))?.clone(),
            None => one_pair_intrinsics(self, index),
        }
    }

    fn sensor_extrinsic(&self, index: u8) -> Option<ExtrinsicRecord> {
        match &self.rig {
            Some(rig) => *rig.extrinsics.get(usize::from(index))?,
            None => one_pair_extrinsic(self, index),
        }
    }

    fn start_calibration(&mut self) -> Result<(), Refusal> {
        if self.refuse_start {
            return Err(Refusal::NotAvailable);
        }
        if self.running.is_some() {
            return Err(Refusal::Busy);
        }
        self.running = Some(self.run_polls);
        self.runs_started += 1;
        self.state.state = DaemonState::Solving;
        Ok(())
    }

    fn calibration_finished(&mut self) -> Option<Outcome> {
        let left = self.running?;
        if left > 0 {
            self.running = Some(left - 1);
            return None;
        }
        self.running = None;
        self.state.state = self.run_result;
        if self.run_result == DaemonState::Accepted {
            self.state.generation += 1;
            self.state.time += 1;
        }
        Some(Outcome { state: self.run_result, generation: self.state.generation })
    }

    fn rollback(&mut self) -> Result<u32, Refusal> {
        if self.running.is_some() {
            return Err(Refusal::Busy);
        }
        if self.state.generation <= 1 {
            return Err(Refusal::NotAvailable);
        }
        self.state.generation -= 1;
        Ok(self.state.generation)
    }
}
