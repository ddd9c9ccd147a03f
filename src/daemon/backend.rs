//! The UDS [`Backend`] on the daemon's state and store: DID 0xC001–0xC004 from the
//! calibration in force; the sensor table (0xC010) and per-sensor DIDs (0xC200 + i,
//! 0xC300 + i) of the rig in force when the record is a rig's (its sensors in the rig
//! file's order: cameras, then LiDARs), else of the configured vehicle; routine 0xC100 start = a run request, 0xC101 = store rollback;
//! and the daemon's service task, which runs the UDS server on the configured transport.

use std::sync::{Arc, Mutex};

use tokio::sync::{mpsc, watch};

use crate::geometry::se3::rotation_to_quaternion;
use crate::geometry::{CameraModel as GeoModel, Se3};
use crate::result::{CameraResult, RigResult};
use crate::service::endpoint::Endpoint;
use crate::service::transport::{CanTransport, TransportError};
use crate::service::uds::{
    Backend, CameraModel, DaemonState, ExtrinsicRecord, IntrinsicsRecord, Outcome, QualityRecord,
    Refusal, SensorKind, SensorTable, StateRecord,
};
use crate::service::{driver, isotp, socketcand::SocketcandServer, uds};
use crate::store::{Lockout, Record, Store};
use std::time::Duration;

use super::config::{ServiceConfig, SocketcandRole};

/// DID 0xC002's record of a camera; `None` when its distortion does not fit.
fn intrinsics_record(c: &CameraResult) -> Option<IntrinsicsRecord> {
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

/// DID 0xC003's record of a rigid motion (quaternion w x y z, translation).
fn extrinsic_record(e: &Se3) -> ExtrinsicRecord {
    let q = rotation_to_quaternion(&e.rotation);
    ExtrinsicRecord {
        rotation: q.map(|v| v as f32),
        translation: [e.translation.x as f32, e.translation.y as f32, e.translation.z as f32],
    }
}

/// The sensor table of a rig in force, in [`RigResult::in_order`]'s order; `None` when it
/// does not fit the table (the configured one is served then).
fn rig_table(rig: &RigResult) -> Option<SensorTable> {
    let kind = |camera: bool| if camera { SensorKind::Camera } else { SensorKind::Lidar };
    SensorTable::of(rig.in_order().iter().map(|s| (kind(s.camera.is_some()), s.name))).ok()
}

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
    /// The vehicle's sensors (DID 0xC010).
    sensors: SensorTable,
}

impl DaemonBackend {
    /// A backend reading `shared`, requesting runs on `requests`, rolling back `store`,
    /// describing the vehicle as `sensors`.
    pub fn new(
        shared: Arc<Mutex<Shared>>,
        requests: mpsc::Sender<()>,
        store: Store,
        sensors: SensorTable,
    ) -> Self {
        DaemonBackend { shared, requests, store, pending: None, sensors }
    }

    fn snapshot(&self) -> Shared {
        self.shared.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// The shared state after checking `current.json` (restored when damaged): every DID
    /// read goes through here, so a tool never reads a record the store no longer holds.
    fn fresh(&self) -> Shared {
        super::verify_store(&self.store, &self.shared);
        self.snapshot()
    }
}

impl Backend for DaemonBackend {
    fn state(&self) -> StateRecord {
        let s = self.fresh();
        let (generation, time) = s.current.as_ref().map_or((0, 0), |r| (r.generation, r.time));
        StateRecord { state: s.state, generation, time: time.min(u64::from(u32::MAX)) as u32 }
    }

    fn intrinsics(&self) -> Option<IntrinsicsRecord> {
        let s = self.fresh();
        intrinsics_record(&s.current.as_ref()?.pair().camera)
    }

    fn extrinsic(&self) -> Option<ExtrinsicRecord> {
        let s = self.fresh();
        Some(extrinsic_record(&s.current.as_ref()?.pair().lidar_to_camera.as_ref()?.to_se3()))
    }

    fn quality(&self) -> Option<QualityRecord> {
        let s = self.fresh();
        let q = &s.current.as_ref()?.pair().quality;
        Some(QualityRecord {
            corner_rms_px: q.corner_rms_px as f32,
            hole_rms_px: q.hole_rms_px as f32,
            boards: q.boards.min(255) as u8,
        })
    }

    fn sensors(&self) -> SensorTable {
        let fresh = self.fresh();
        let rig = fresh.current.as_ref().and_then(Record::rig);
        rig.and_then(rig_table).unwrap_or_else(|| self.sensors.clone())
    }

    fn sensor_intrinsics(&self, index: u8) -> Option<IntrinsicsRecord> {
        match self.fresh().current.as_ref().and_then(Record::rig) {
            Some(rig) => intrinsics_record(rig.in_order().get(usize::from(index))?.camera?),
            None => uds::one_pair_intrinsics(self, index),
        }
    }

    fn sensor_extrinsic(&self, index: u8) -> Option<ExtrinsicRecord> {
        match self.fresh().current.as_ref().and_then(Record::rig) {
            Some(rig) => Some(extrinsic_record(&rig.in_order().get(usize::from(index))?.to_first)),
            None => uds::one_pair_extrinsic(self, index),
        }
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

    fn security_changed(&mut self, failed_attempts: u8, locked_for: Option<Duration>) {
        let now = super::unix_now();
        // Whole seconds, rounded up: the lock never ends early after a restart.
        let locked_until =
            locked_for.map_or(0, |d| now + d.as_secs() + u64::from(d.subsec_nanos() > 0));
        if let Err(e) = self.store.set_lockout(&Lockout { failed_attempts, locked_until }) {
            tracing::error!("SecurityAccess lockout not kept: {e}");
        }
    }

    fn rollback(&mut self) -> Result<u32, Refusal> {
        if matches!(self.snapshot().state, DaemonState::Capturing | DaemonState::Solving) {
            return Err(Refusal::Busy);
        }
        // A few small fsync'ed files: short enough for the protocol loop.
        match self.store.rollback(super::unix_now()) {
            Ok(rec) => {
                let generation = rec.generation;
                match rec.restored_from {
                    Some(from) => tracing::info!(
                        "rolled back: generation {generation} restores generation {from}"
                    ),
                    None => tracing::info!("rolled back: generation {generation} in force"),
                }
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

/// The UDS server the service task runs.
type DaemonServer = uds::Server<DaemonBackend, driver::OsRandom>;

/// Service task: the UDS server on the configured transport until `stop` turns true. A
/// `socketcand:` endpoint is served (listen, the default) or connected to; a failed
/// bind, connection or interface is retried with backoff.
pub(crate) async fn service_task(
    cfg: ServiceConfig,
    backend: DaemonBackend,
    mut stop: watch::Receiver<bool>,
) {
    let secret = match crate::service::client::read_vehicle_secret(&cfg.secret_file) {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("service disabled: {e}");
            return;
        }
    };
    let Ok(endpoint) = Endpoint::parse(&cfg.transport) else {
        return; // checked when the configuration was loaded
    };
    let Ok(seeds) = driver::OsRandom::open() else {
        tracing::error!("service disabled: /dev/urandom cannot be opened");
        return;
    };
    let server_cfg = uds::ServerConfig::default();
    let kept = backend.store.lockout(super::unix_now(), server_cfg.lockout.as_secs());
    let mut server = uds::Server::new(backend, seeds, &secret, server_cfg);
    let locked_for = kept.locked_until.saturating_sub(super::unix_now());
    // The driver's clock starts at zero when it serves.
    let locked_for = (locked_for > 0).then(|| Duration::from_secs(locked_for));
    server.restore_security(
        kept.failed_attempts,
        locked_for,
        crate::service::Instant::from_micros(0),
    );
    if let Some(d) = locked_for {
        tracing::warn!(
            "SecurityAccess locked for {} s more (wrong keys before the restart)",
            d.as_secs()
        );
    }
    let tp = isotp::Config::new(cfg.response_id, cfg.request_id);
    let mut backoff = crate::capture::Backoff::default();
    while !*stop.borrow() {
        let served = match (&endpoint, cfg.socketcand) {
            (Endpoint::Socketcand { addr, channel }, SocketcandRole::Listen) => {
                match SocketcandServer::bind(addr, channel).await {
                    Ok(mut t) => {
                        backoff.reset();
                        let local = t.local_addr();
                        tracing::info!("service: socketcand endpoint listening on {local}");
                        serve_until_stopped(&mut t, &mut server, tp, &stop).await
                    }
                    Err(e) => Err(e),
                }
            }
            _ => match endpoint.connect().await {
                Ok(mut t) => {
                    backoff.reset();
                    tracing::info!("service on {}", cfg.transport);
                    serve_until_stopped(&mut t, &mut server, tp, &stop).await
                }
                Err(e) => Err(e),
            },
        };
        if let Err(e) = served {
            tracing::warn!("service: {e}");
        }
        let d = backoff.next_delay();
        tokio::select! {
            _ = tokio::time::sleep(d) => {}
            _ = stop.wait_for(|v| *v) => return,
        }
    }
}

async fn serve_until_stopped<T: CanTransport>(
    transport: &mut T,
    server: &mut DaemonServer,
    tp: isotp::Config,
    stop: &watch::Receiver<bool>,
) -> Result<(), TransportError> {
    let mut s = stop.clone();
    let stopped = async move {
        let _ = s.wait_for(|v| *v).await;
    };
    driver::serve(transport, server, tp, stopped).await
}
