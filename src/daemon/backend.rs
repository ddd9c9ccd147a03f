//! The UDS [`Backend`] on the daemon's state and store: DID 0xC001–0xC004 from the
//! calibration in force, routine 0xC100 start = a run request, 0xC101 = store rollback.

use std::sync::{Arc, Mutex};

use tokio::sync::mpsc;

use crate::geometry::se3::rotation_to_quaternion;
use crate::geometry::CameraModel as GeoModel;
use crate::service::uds::{
    Backend, CameraModel, DaemonState, ExtrinsicRecord, IntrinsicsRecord, Outcome, QualityRecord,
    Refusal, StateRecord,
};
use crate::store::{Record, Store};

/// What the daemon shares with the service and the handle.
#[derive(Clone, Debug)]
pub struct Shared {
    pub state: DaemonState,
    pub current: Option<Record>,
    /// Runs finished so far, and how the last one ended.
    pub runs: u64,
    pub last: Option<Outcome>,
}

impl Default for Shared {
    fn default() -> Self {
        Shared { state: DaemonState::Idle, current: None, runs: 0, last: None }
    }
}

/// The daemon's UDS backend.
pub struct DaemonBackend {
    shared: Arc<Mutex<Shared>>,
    requests: mpsc::Sender<()>,
    store: Store,
    /// `runs` when the service started a run.
    pending: Option<u64>,
}

impl DaemonBackend {
    /// A backend reading `shared`, requesting runs on `requests`, rolling back `store`.
    pub fn new(shared: Arc<Mutex<Shared>>, requests: mpsc::Sender<()>, store: Store) -> Self {
        DaemonBackend { shared, requests, store, pending: None }
    }

    fn snapshot(&self) -> Shared {
        self.shared.lock().map(|s| s.clone()).unwrap_or_default()
    }
}

impl Backend for DaemonBackend {
    fn state(&self) -> StateRecord {
        let s = self.snapshot();
        let (generation, time) = s.current.as_ref().map_or((0, 0), |r| (r.generation, r.time));
        StateRecord { state: s.state, generation, time: time.min(u64::from(u32::MAX)) as u32 }
    }

    fn intrinsics(&self) -> Option<IntrinsicsRecord> {
        let s = self.snapshot();
        let c = &s.current.as_ref()?.result.camera;
        let mut distortion = heapless::Vec::new();
        for d in &c.distortion {
            distortion.push(*d as f32).ok()?;
        }
        Some(IntrinsicsRecord {
            model: match c.model {
                GeoModel::PinholeRadtan => CameraModel::PinholeRadtan,
                GeoModel::Fisheye => CameraModel::Fisheye,
            },
            fx: c.fx as f32,
            fy: c.fy as f32,
            cx: c.cx as f32,
            cy: c.cy as f32,
            distortion,
        })
    }

    fn extrinsic(&self) -> Option<ExtrinsicRecord> {
        let s = self.snapshot();
        let e = s.current.as_ref()?.result.lidar_to_camera.as_ref()?.to_se3();
        let q = rotation_to_quaternion(&e.rotation);
        Some(ExtrinsicRecord {
            rotation: q.map(|v| v as f32),
            translation: [e.translation.x as f32, e.translation.y as f32, e.translation.z as f32],
        })
    }

    fn quality(&self) -> Option<QualityRecord> {
        let s = self.snapshot();
        let q = &s.current.as_ref()?.result.quality;
        Some(QualityRecord {
            corner_rms_px: q.corner_rms_px as f32,
            hole_rms_px: q.hole_rms_px as f32,
            boards: q.boards.min(255) as u8,
        })
    }

    fn start_calibration(&mut self) -> Result<(), Refusal> {
        let s = self.snapshot();
        if matches!(s.state, DaemonState::Capturing | DaemonState::Solving) {
            return Err(Refusal::Busy);
        }
        self.requests.try_send(()).map_err(|_| Refusal::Busy)?;
        self.pending = Some(s.runs);
        Ok(())
    }

    fn calibration_finished(&mut self) -> Option<Outcome> {
        let started = self.pending?;
        let s = self.snapshot();
        if s.runs > started {
            self.pending = None;
            return s.last;
        }
        None
    }

    fn rollback(&mut self) -> Result<u32, Refusal> {
        if matches!(self.snapshot().state, DaemonState::Capturing | DaemonState::Solving) {
            return Err(Refusal::Busy);
        }
        // A few small fsync'ed files: short enough for the protocol loop.
        match self.store.rollback(super::unix_now()) {
            Ok(rec) => {
                let generation = rec.generation;
                tracing::info!(generation, restored_from = ?rec.restored_from, "rolled back");
                if let Ok(mut s) = self.shared.lock() {
                    s.current = Some(rec);
                }
                Ok(generation)
            }
            Err(crate::store::StoreError::NoPrevious { .. }) => Err(Refusal::NotAvailable),
            Err(e) => {
                tracing::error!("rollback failed: {e}");
                Err(Refusal::Failed)
            }
        }
    }
}
