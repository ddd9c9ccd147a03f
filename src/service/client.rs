//! UDS client for roomcal's service interface (std, tokio) and the pieces of
//! `roomcal query --endpoint ENDPOINT status|sensors|intrinsics[:SENSOR]|extrinsic[:SENSOR]|quality|start|rollback`.

use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Duration;

use super::endpoint::Endpoint;
use super::isotp::{self, Event, IsoTp};
use super::transport::{CanTransport, TransportError};
use super::uds::{
    did, rid, security_key, sid, DecodeError, ExtrinsicRecord, IntrinsicsRecord, Nrc, Outcome,
    QualityRecord, RequestRepr, ResponseRepr, SensorKind, SensorTable, Session, StateRecord,
    SEED_LEN,
};
use super::{Instant, DEFAULT_REQUEST_ID, DEFAULT_RESPONSE_ID};

/// Errors of the client; each names what was asked.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("no response to service 0x{service:02X} within {timeout:?}")]
    Timeout { service: u8, timeout: Duration },
    #[error("service 0x{service:02X} refused: {}", describe_nrc(*nrc))]
    Negative { service: u8, nrc: u8 },
    /// A negative response `roomcal query` can explain in the daemon's terms.
    #[error("service 0x{service:02X} refused: {} ({hint})", describe_nrc(*nrc))]
    Refused { service: u8, nrc: u8, hint: &'static str },
    #[error("ISO-TP: {0}")]
    IsoTp(String),
    #[error("unexpected response to service 0x{service:02X}: {bytes:02X?}")]
    Unexpected { service: u8, bytes: Vec<u8> },
    #[error("DID 0x{did:04X}: {error}")]
    Decode { did: u16, error: DecodeError },
    #[error("cannot read the secret file {path}: {source}")]
    Secret { path: PathBuf, source: std::io::Error },
    #[error("secret file {0} is empty")]
    EmptySecret(PathBuf),
    #[error("secret file {path}: {problem}; the service stays off until it is fixed")]
    ExposedSecret { path: PathBuf, problem: String },
    #[error("`{0}` needs --secret-file")]
    NeedsSecret(&'static str),
    #[error(
        "unknown query `{0}`: expected status, sensors, intrinsics[:SENSOR], extrinsic[:SENSOR], \
         quality, start or rollback (SENSOR: a name or an index of `sensors`)"
    )]
    UnknownQuery(String),
    #[error("no sensor `{name}` on this vehicle; its sensors: {known}")]
    UnknownSensor { name: String, known: String },
    #[error("cannot start the async runtime: {0}")]
    Runtime(std::io::Error),
}

fn describe_nrc(nrc: u8) -> String {
    match Nrc::from_u8(nrc) {
        Some(n) => n.to_string(),
        None => format!("NRC 0x{nrc:02X}"),
    }
}

/// Client timing.
#[derive(Clone, Copy, Debug)]
pub struct ClientTiming {
    /// Wait for the first response (P2 client; generous over the server's 50 ms).
    pub p2: Duration,
    /// Wait after each 0x78 responsePending (P2* client, over the server's 5000 ms).
    pub p2_star: Duration,
}

impl Default for ClientTiming {
    fn default() -> Self {
        ClientTiming { p2: Duration::from_millis(1000), p2_star: Duration::from_millis(6000) }
    }
}

/// A UDS client on one CAN transport.
pub struct UdsClient<T: CanTransport> {
    transport: T,
    tp: Box<IsoTp>,
    epoch: tokio::time::Instant,
    timing: ClientTiming,
}

impl<T: CanTransport> UdsClient<T> {
    /// A client whose ISO-TP endpoint is `cfg` (tx = request ID, rx = response ID).
    pub fn new(transport: T, cfg: isotp::Config, timing: ClientTiming) -> Self {
        UdsClient {
            transport,
            tp: Box::new(IsoTp::new(cfg)),
            epoch: tokio::time::Instant::now(),
            timing,
        }
    }

    /// A client with the default IDs (0x7A0 → 0x7A8) and timing.
    pub fn with_defaults(transport: T) -> Self {
        Self::new(
            transport,
            isotp::Config::new(DEFAULT_REQUEST_ID, DEFAULT_RESPONSE_ID),
            ClientTiming::default(),
        )
    }

    fn now(&self) -> Instant {
        Instant::from_micros(self.epoch.elapsed().as_micros() as u64)
    }

    /// Sends `request` and returns the positive response (SID byte included).
    /// 0x78 responsePending extends the wait to P2*; negative responses are errors.
    pub async fn request(&mut self, request: &[u8]) -> Result<Vec<u8>, ClientError> {
        let service = request.first().copied().unwrap_or(0);
        self.tp.send(request).map_err(|e| ClientError::IsoTp(e.to_string()))?;
        let mut timeout = self.timing.p2;
        let mut deadline = tokio::time::Instant::now() + timeout;
        loop {
            let response = self.next_message(deadline, service, timeout).await?;
            match ResponseRepr::parse(&response) {
                Some(ResponseRepr::Negative { service: s, nrc }) if s == service => {
                    if nrc == Nrc::ResponsePending as u8 {
                        timeout = self.timing.p2_star;
                        deadline = tokio::time::Instant::now() + timeout;
                        continue;
                    }
                    return Err(ClientError::Negative { service, nrc });
                }
                Some(ResponseRepr::Positive { service: s, .. }) if s == service => {
                    return Ok(response)
                }
                _ => return Err(ClientError::Unexpected { service, bytes: response }),
            }
        }
    }

    /// Pumps frames both ways until a whole message arrives or `deadline` passes.
    async fn next_message(
        &mut self,
        deadline: tokio::time::Instant,
        service: u8,
        timeout: Duration,
    ) -> Result<Vec<u8>, ClientError> {
        loop {
            while let Some(frame) = self.tp.poll_transmit(self.now()) {
                self.transport.send(&frame).await?;
                if let Some(Event::TxAborted(e)) = self.tp.frame_sent(self.now()) {
                    return Err(ClientError::IsoTp(e.to_string()));
                }
            }
            match self.tp.poll(self.now()) {
                Some(Event::TxAborted(e)) => return Err(ClientError::IsoTp(e.to_string())),
                Some(Event::RxAborted(e)) => return Err(ClientError::IsoTp(e.to_string())),
                _ => {}
            }
            let wake = self.tp.poll_at().map_or(deadline, |t| {
                (self.epoch + Duration::from_micros(t.as_micros())).min(deadline)
            });
            tokio::select! {
                frame = self.transport.recv() => {
                    let frame = frame?;
                    match self.tp.on_frame(&frame, self.now()) {
                        Some(Event::Received(_)) => return Ok(self.tp.received().to_vec()),
                        Some(Event::RxAborted(e)) => return Err(ClientError::IsoTp(e.to_string())),
                        _ => {}
                    }
                }
                _ = tokio::time::sleep_until(wake) => {
                    if tokio::time::Instant::now() >= deadline {
                        return Err(ClientError::Timeout { service, timeout });
                    }
                }
            }
        }
    }

    /// Sends a request built from its representation; returns the positive response.
    pub async fn request_repr(&mut self, request: &RequestRepr) -> Result<Vec<u8>, ClientError> {
        let mut buf = [0u8; 64];
        let n = request.emit(&mut buf).unwrap_or(0);
        self.request(&buf[..n]).await
    }

    /// ReadDataByIdentifier for one DID; returns the record bytes.
    pub async fn read_did(&mut self, id: u16) -> Result<Vec<u8>, ClientError> {
        let [hi, lo] = id.to_be_bytes();
        let dids = heapless::Vec::from_slice(&[id]).unwrap_or_default();
        let r = self.request_repr(&RequestRepr::ReadData { dids }).await?;
        match r.get(1..3) {
            Some(echo) if echo == [hi, lo] => Ok(r[3..].to_vec()),
            _ => Err(ClientError::Unexpected { service: sid::READ_DATA_BY_IDENTIFIER, bytes: r }),
        }
    }

    /// DID 0xC001.
    pub async fn status(&mut self) -> Result<StateRecord, ClientError> {
        let b = self.read_did(did::STATE).await?;
        StateRecord::parse(&b).map_err(|error| ClientError::Decode { did: did::STATE, error })
    }

    /// DID 0xC002.
    pub async fn intrinsics(&mut self) -> Result<IntrinsicsRecord, ClientError> {
        let b = self.read_did(did::INTRINSICS).await?;
        IntrinsicsRecord::parse(&b)
            .map_err(|error| ClientError::Decode { did: did::INTRINSICS, error })
    }

    /// DID 0xC003.
    pub async fn extrinsic(&mut self) -> Result<ExtrinsicRecord, ClientError> {
        let b = self.read_did(did::EXTRINSIC).await?;
        ExtrinsicRecord::parse(&b)
            .map_err(|error| ClientError::Decode { did: did::EXTRINSIC, error })
    }

    /// DID 0xC004.
    pub async fn quality(&mut self) -> Result<QualityRecord, ClientError> {
        let b = self.read_did(did::QUALITY).await?;
        QualityRecord::parse(&b).map_err(|error| ClientError::Decode { did: did::QUALITY, error })
    }

    /// DID 0xC010.
    pub async fn sensors(&mut self) -> Result<SensorTable, ClientError> {
        let b = self.read_did(did::SENSORS).await?;
        SensorTable::parse(&b).map_err(|error| ClientError::Decode { did: did::SENSORS, error })
    }

    /// DID 0xC200 + `index`: camera `index`'s intrinsics.
    pub async fn sensor_intrinsics(&mut self, index: u8) -> Result<IntrinsicsRecord, ClientError> {
        let id = did::SENSOR_INTRINSICS + u16::from(index);
        let b = self.read_did(id).await?;
        IntrinsicsRecord::parse(&b).map_err(|error| ClientError::Decode { did: id, error })
    }

    /// DID 0xC300 + `index`: sensor `index` → the first camera.
    pub async fn sensor_extrinsic(&mut self, index: u8) -> Result<ExtrinsicRecord, ClientError> {
        let id = did::SENSOR_EXTRINSIC + u16::from(index);
        let b = self.read_did(id).await?;
        ExtrinsicRecord::parse(&b).map_err(|error| ClientError::Decode { did: id, error })
    }

    /// The index, name and kind of `sensor`, from the sensor table (read from the server).
    pub async fn resolve(
        &mut self,
        sensor: &SensorRef,
    ) -> Result<(u8, String, SensorKind), ClientError> {
        let table = self.sensors().await?;
        let index = match sensor {
            SensorRef::Index(i) => Some(*i).filter(|&i| usize::from(i) < table.sensors.len()),
            SensorRef::Name(name) => table.index_of(name),
        };
        let found = index.and_then(|i| {
            let entry = table.sensors.get(usize::from(i))?;
            Some((i, entry.name.to_string(), entry.kind))
        });
        found.ok_or_else(|| ClientError::UnknownSensor {
            name: match sensor {
                SensorRef::Index(i) => i.to_string(),
                SensorRef::Name(n) => n.clone(),
            },
            known: table.sensors.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", "),
        })
    }

    /// DiagnosticSessionControl; returns the server's (P2, P2*) timing.
    pub async fn session(&mut self, session: Session) -> Result<(Duration, Duration), ClientError> {
        let r =
            self.request_repr(&RequestRepr::SessionControl { session, suppress: false }).await?;
        match r[..] {
            [_, s, a, b, c, d] if s == session as u8 => Ok((
                Duration::from_millis(u64::from(u16::from_be_bytes([a, b]))),
                Duration::from_millis(10 * u64::from(u16::from_be_bytes([c, d]))),
            )),
            _ => {
                Err(ClientError::Unexpected { service: sid::DIAGNOSTIC_SESSION_CONTROL, bytes: r })
            }
        }
    }

    /// TesterPresent (with a response).
    pub async fn tester_present(&mut self) -> Result<(), ClientError> {
        self.request_repr(&RequestRepr::TesterPresent { suppress: false }).await.map(drop)
    }

    /// SecurityAccess: seed, then key = HMAC-SHA256(secret, seed)[..16].
    pub async fn unlock(&mut self, secret: &[u8]) -> Result<(), ClientError> {
        let r = self.request_repr(&RequestRepr::RequestSeed { suppress: false }).await?;
        let Some(seed) = r.get(2..2 + SEED_LEN).filter(|_| r.len() == 2 + SEED_LEN) else {
            return Err(ClientError::Unexpected { service: sid::SECURITY_ACCESS, bytes: r });
        };
        // An all-zero seed means already unlocked.
        if seed.iter().all(|&b| b == 0) {
            return Ok(());
        }
        let key = security_key(secret, seed);
        self.request_repr(&RequestRepr::SendKey { key, suppress: false }).await.map(drop)
    }

    /// RoutineControl 0xC100 start: runs a calibration and waits for its outcome.
    pub async fn start_calibration(&mut self) -> Result<Outcome, ClientError> {
        let r = self.routine(0x01, rid::START_CALIBRATION).await?;
        Outcome::parse(&r)
            .map_err(|error| ClientError::Decode { did: rid::START_CALIBRATION, error })
    }

    /// RoutineControl 0xC100 results: the last run's outcome.
    pub async fn calibration_results(&mut self) -> Result<Outcome, ClientError> {
        let r = self.routine(0x03, rid::START_CALIBRATION).await?;
        Outcome::parse(&r)
            .map_err(|error| ClientError::Decode { did: rid::START_CALIBRATION, error })
    }

    /// RoutineControl 0xC101 start: roll back; returns the generation now in force.
    pub async fn rollback(&mut self) -> Result<u32, ClientError> {
        let r = self.routine(0x01, rid::ROLLBACK).await?;
        match r[..] {
            [a, b, c, d] => Ok(u32::from_be_bytes([a, b, c, d])),
            _ => Err(ClientError::Unexpected { service: sid::ROUTINE_CONTROL, bytes: r }),
        }
    }

    /// RoutineControl; returns the status record after the echoed sub-function and RID.
    async fn routine(&mut self, sub: u8, routine: u16) -> Result<Vec<u8>, ClientError> {
        let [hi, lo] = routine.to_be_bytes();
        let repr = RequestRepr::RoutineControl { sub, routine, suppress: false };
        let r = self.request_repr(&repr).await?;
        match r.get(1..4) {
            Some(echo) if echo == [sub, hi, lo] => Ok(r[4..].to_vec()),
            _ => Err(ClientError::Unexpected { service: sid::ROUTINE_CONTROL, bytes: r }),
        }
    }
}

/// What `roomcal query` asks.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum QueryCommand {
    Status,
    /// The sensor table (DID 0xC010).
    Sensors,
    /// DID 0xC002, or a camera's 0xC200 + index.
    Intrinsics(Option<SensorRef>),
    /// DID 0xC003 (LiDAR → camera), or a sensor's 0xC300 + index (→ the first camera).
    Extrinsic(Option<SensorRef>),
    Quality,
    Start,
    Rollback,
}

/// A sensor named in a query: by its index in the sensor table, or by its rig name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SensorRef {
    Index(u8),
    Name(String),
}

impl FromStr for QueryCommand {
    type Err = ClientError;

    fn from_str(s: &str) -> Result<Self, ClientError> {
        let (what, sensor) = match s.split_once(':') {
            Some((what, sensor)) if !sensor.is_empty() => (what, Some(sensor)),
            Some(_) => return Err(ClientError::UnknownQuery(s.to_string())),
            None => (s, None),
        };
        let sensor =
            sensor.map(|t| t.parse().map_or(SensorRef::Name(t.to_string()), SensorRef::Index));
        Ok(match what {
            "intrinsics" => QueryCommand::Intrinsics(sensor),
            "extrinsic" => QueryCommand::Extrinsic(sensor),
            _ if sensor.is_some() => return Err(ClientError::UnknownQuery(s.to_string())),
            "status" => QueryCommand::Status,
            "sensors" => QueryCommand::Sensors,
            "quality" => QueryCommand::Quality,
            "start" => QueryCommand::Start,
            "rollback" => QueryCommand::Rollback,
            other => return Err(ClientError::UnknownQuery(other.to_string())),
        })
    }
}

/// Options of `roomcal query`.
#[derive(Clone, Debug)]
pub struct QueryOptions {
    /// `socketcand:HOST:PORT[/CHANNEL]` or `socketcan:IFACE`.
    pub endpoint: String,
    pub request_id: u32,
    pub response_id: u32,
    /// Vehicle secret for `start` and `rollback` (whole file, bytes as they are).
    pub secret_file: Option<PathBuf>,
    pub timing: ClientTiming,
}

impl QueryOptions {
    /// Default IDs and timing, no secret.
    pub fn new(endpoint: &str) -> Self {
        QueryOptions {
            endpoint: endpoint.to_string(),
            request_id: DEFAULT_REQUEST_ID,
            response_id: DEFAULT_RESPONSE_ID,
            secret_file: None,
            timing: ClientTiming::default(),
        }
    }
}

/// Reads the vehicle secret: the whole file, one trailing newline removed.
pub fn read_secret(path: &Path) -> Result<Vec<u8>, ClientError> {
    let mut secret = std::fs::read(path)
        .map_err(|source| ClientError::Secret { path: path.to_path_buf(), source })?;
    if secret.last() == Some(&b'\n') {
        secret.pop();
    }
    if secret.is_empty() {
        return Err(ClientError::EmptySecret(path.to_path_buf()));
    }
    Ok(secret)
}

/// The vehicle secret as the daemon may use it, refused unless only the daemon can read it:
/// the file must belong to this process's user or to root and grant nothing to group or
/// others (mode 0600 or 0400), as ssh demands of a private key. Anyone who can read the
/// secret can unlock every routine of every vehicle that shares it.
pub fn read_vehicle_secret(path: &Path) -> Result<Vec<u8>, ClientError> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let meta = std::fs::metadata(path)
        .map_err(|source| ClientError::Secret { path: path.to_path_buf(), source })?;
    let exposed =
        |problem: String| ClientError::ExposedSecret { path: path.to_path_buf(), problem };
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        return Err(exposed(format!(
            "mode {mode:04o} lets group or others read it (chmod 600 {})",
            path.display()
        )));
    }
    // /proc/self belongs to the process's effective user (std has no geteuid).
    let me = std::fs::metadata("/proc/self").map(|m| m.uid()).ok();
    let owner = meta.uid();
    if let Some(me) = me.filter(|&me| owner != 0 && owner != me) {
        return Err(exposed(format!(
            "it belongs to uid {owner}, not to this process's user (uid {me}) or root"
        )));
    }
    read_secret(path)
}

/// Runs one query and returns the human-readable answer.
pub async fn query(opts: &QueryOptions, cmd: QueryCommand) -> Result<String, ClientError> {
    // Read the secret before touching the bus: a missing file is the likelier mistake.
    let secret = match &cmd {
        QueryCommand::Start | QueryCommand::Rollback => {
            let path = opts.secret_file.as_deref().ok_or(ClientError::NeedsSecret(
                if cmd == QueryCommand::Start { "start" } else { "rollback" },
            ))?;
            Some(read_secret(path)?)
        }
        _ => None,
    };
    let transport = Endpoint::parse(&opts.endpoint)?.connect().await?;
    let cfg = isotp::Config::new(opts.request_id, opts.response_id);
    let mut client = UdsClient::new(transport, cfg, opts.timing);
    run_query(&mut client, &cmd, secret.as_deref()).await.map_err(|e| explain(&cmd, e))
}

/// What a refusal means for the daemon, for the few that have one meaning.
fn explain(cmd: &QueryCommand, e: ClientError) -> ClientError {
    let ClientError::Negative { service, nrc } = e else {
        return e;
    };
    let hint = match (cmd, nrc) {
        (_, 0x21) => "a calibration started over UDS is still running",
        (
            QueryCommand::Intrinsics(_) | QueryCommand::Extrinsic(_) | QueryCommand::Quality,
            0x22,
        ) => "no calibration in force yet (or none of this kind)",
        (QueryCommand::Intrinsics(Some(_)) | QueryCommand::Extrinsic(Some(_)), 0x31) => {
            "no such sensor (or a LiDAR, which has no intrinsics): see `sensors`"
        }
        (QueryCommand::Start, 0x22) => "a calibration is already running",
        (QueryCommand::Rollback, 0x22) => "no earlier calibration to roll back to, or a run is on",
        (QueryCommand::Start | QueryCommand::Rollback, 0x35) => "the secret file does not match",
        (QueryCommand::Start | QueryCommand::Rollback, 0x36 | 0x37) => {
            "too many wrong keys: SecurityAccess is locked for a while"
        }
        _ => return e,
    };
    ClientError::Refused { service, nrc, hint }
}

async fn run_query<T: CanTransport>(
    client: &mut UdsClient<T>,
    cmd: &QueryCommand,
    secret: Option<&[u8]>,
) -> Result<String, ClientError> {
    let text = match cmd {
        QueryCommand::Status => client.status().await?.to_string(),
        QueryCommand::Sensors => client.sensors().await?.to_string(),
        QueryCommand::Intrinsics(None) => client.intrinsics().await?.to_string(),
        QueryCommand::Extrinsic(None) => client.extrinsic().await?.to_string(),
        QueryCommand::Intrinsics(Some(sensor)) => {
            let (index, name, _) = client.resolve(sensor).await?;
            format!("camera {name} ({index}):\n{}", client.sensor_intrinsics(index).await?)
        }
        QueryCommand::Extrinsic(Some(sensor)) => {
            let (index, name, kind) = client.resolve(sensor).await?;
            let record = client.sensor_extrinsic(index).await?;
            let pose = match record.body_pose(kind == SensorKind::Camera) {
                Some(pose) => format!("{pose}"),
                None => record.to_string(),
            };
            format!(
                "sensor {name} ({index}) in the first camera's body frame (x forward, y left, z \
                 up):\n{pose}"
            )
        }
        QueryCommand::Quality => client.quality().await?.to_string(),
        QueryCommand::Start | QueryCommand::Rollback => {
            client.session(Session::Extended).await?;
            client.unlock(secret.unwrap_or_default()).await?;
            if *cmd == QueryCommand::Start {
                client.start_calibration().await?.to_string()
            } else {
                format!("rolled back; generation in force: {}", client.rollback().await?)
            }
        }
    };
    Ok(text)
}

/// [`query`] on a private single-threaded runtime, for the synchronous CLI.
pub fn query_blocking(opts: &QueryOptions, cmd: QueryCommand) -> Result<String, ClientError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(ClientError::Runtime)?;
    rt.block_on(query(opts, cmd))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_secret_others_can_read_is_refused_and_one_only_its_owner_reads_is_used() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("roomcal-secret-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("secret");
        std::fs::write(&path, b"vehicle secret\n").unwrap();
        for mode in [0o644, 0o640, 0o604, 0o660] {
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).unwrap();
            let e = read_vehicle_secret(&path).unwrap_err().to_string();
            assert!(e.contains(&format!("mode {mode:04o}")) && e.contains("chmod 600"), "{e}");
        }
        for mode in [0o600, 0o400] {
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).unwrap();
            assert_eq!(read_vehicle_secret(&path).unwrap(), b"vehicle secret");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
