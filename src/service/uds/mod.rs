//! UDS (ISO 14229-1) server for roomcal's service interface, and the wire encodings of
//! its data identifiers and routine results.
//!
//! The [`Server`] is a sans-I/O state machine: [`Server::handle`] takes one request
//! message (as ISO-TP delivered it) and returns the response to send, if any;
//! [`Server::poll`] runs the timers (S3 session timeout, the periodic 0x78
//! responsePending while a calibration runs, and the final answer once the
//! [`Backend`] reports it). Time is passed in; randomness for SecurityAccess seeds comes
//! from a caller-supplied [`SeedSource`]. [`Link`] puts the server on an ISO-TP endpoint
//! and binds each response to the request it answers.
//!
//! Services (see DESIGN.md, "Service over CAN"):
//!
//! | SID  | service | sessions | sub-functions |
//! |------|---------|----------|---------------|
//! | 0x10 | DiagnosticSessionControl | all | 0x01 default, 0x03 extended |
//! | 0x3E | TesterPresent | all | 0x00 |
//! | 0x27 | SecurityAccess | extended | 0x01 requestSeed, 0x02 sendKey |
//! | 0x22 | ReadDataByIdentifier | all | – (DIDs 0xC001–0xC004, 0xC010, 0xC200 + i, 0xC300 + i) |
//! | 0x31 | RoutineControl | extended, unlocked | 0x01 start, 0x03 results (RIDs 0xC100, 0xC101) |
//!
//! Negative responses follow the NRC evaluation order of ISO 14229-1:2013 (7.5):
//! SID supported (0x11) → SID supported in the active session (0x7F) → minimum length
//! (0x13) → sub-function supported (0x12) → service-specific checks (exact length 0x13,
//! identifier 0x31, security 0x33, sequence 0x24, conditions 0x22). The
//! suppress-positive-response bit (0x80 of the sub-function) is honoured by every
//! service that has a sub-function; negative responses are never suppressed, and once a
//! 0x78 has gone out the final positive response is sent regardless (ISO 14229-1 7.5).

use core::time::Duration;

use hmac::{Hmac, Mac};
use sha2::Sha256;

use super::Instant;

mod link;
mod records;
mod repr;

pub use link::{Abandoned, Link, LinkEvent};
pub use records::*;
pub use repr::{RequestRepr, ResponseRepr};

/// What the UDS server needs from the daemon. Implementations must not block: every
/// method is called from the protocol loop.
pub trait Backend {
    /// Current state and the calibration in force (DID 0xC001).
    fn state(&self) -> StateRecord;
    /// Intrinsics in force (DID 0xC002); `None` before the first calibration
    /// (answered with NRC 0x22).
    fn intrinsics(&self) -> Option<IntrinsicsRecord>;
    /// LiDAR → camera extrinsic in force (DID 0xC003); `None` if there is none.
    fn extrinsic(&self) -> Option<ExtrinsicRecord>;
    /// Quality of the calibration in force (DID 0xC004); `None` if there is none.
    fn quality(&self) -> Option<QualityRecord>;
    /// The vehicle's sensors (DID 0xC010); by default the one-pair rig, camera and LiDAR.
    fn sensors(&self) -> SensorTable {
        SensorTable::one_pair(true)
    }
    /// Intrinsics in force of camera `index` (DIDs 0xC200 + index); by default camera 0's
    /// are [`Backend::intrinsics`].
    fn sensor_intrinsics(&self, index: u8) -> Option<IntrinsicsRecord> {
        one_pair_intrinsics(self, index)
    }
    /// Extrinsic in force of sensor `index` → the first camera (DIDs 0xC300 + index); the
    /// first camera's own is the identity, and by default sensor 1's is
    /// [`Backend::extrinsic`].
    fn sensor_extrinsic(&self, index: u8) -> Option<ExtrinsicRecord> {
        one_pair_extrinsic(self, index)
    }
    /// Starts a calibration run (routine 0xC100 start). Returns at once; the server then
    /// polls [`Backend::calibration_finished`] and answers 0x78 meanwhile.
    fn start_calibration(&mut self) -> Result<(), Refusal>;
    /// `Some` once the run started by `start_calibration` is over.
    fn calibration_finished(&mut self) -> Option<Outcome>;
    /// Puts the previous calibration back in force (routine 0xC101); returns the
    /// generation now in force.
    fn rollback(&mut self) -> Result<u32, Refusal>;
    /// SecurityAccess changed: `failed_attempts` wrong keys in a row, and locked for
    /// `locked_for` from now (`None`: not locked). A backend persists it so that a restart
    /// keeps the lock (see [`Server::restore_security`]); by default it is not kept.
    fn security_changed(&mut self, _failed_attempts: u8, _locked_for: Option<Duration>) {}
}

/// The one-pair rig's camera intrinsics (DIDs 0xC200 + index): camera 0's are DID
/// 0xC002's; there is no other camera.
pub fn one_pair_intrinsics<B: Backend + ?Sized>(
    backend: &B,
    index: u8,
) -> Option<IntrinsicsRecord> {
    (index == 0).then(|| backend.intrinsics())?
}

/// The one-pair rig's extrinsics (DIDs 0xC300 + index): the camera's is the identity, the
/// LiDAR's (sensor 1) DID 0xC003's.
pub fn one_pair_extrinsic<B: Backend + ?Sized>(backend: &B, index: u8) -> Option<ExtrinsicRecord> {
    match index {
        0 => Some(ExtrinsicRecord::IDENTITY),
        1 => backend.extrinsic(),
        _ => None,
    }
}

/// Source of SecurityAccess seeds; must be unpredictable (an OS or hardware RNG).
pub trait SeedSource {
    /// Fills `seed` with fresh random bytes.
    fn fill_seed(&mut self, seed: &mut [u8; SEED_LEN]);
}

impl<F: FnMut(&mut [u8; SEED_LEN])> SeedSource for F {
    fn fill_seed(&mut self, seed: &mut [u8; SEED_LEN]) {
        self(seed)
    }
}

/// The SecurityAccess key for `seed`: the first 16 bytes of HMAC-SHA256(secret, seed).
pub fn security_key(secret: &[u8], seed: &[u8]) -> [u8; SEED_LEN] {
    // HMAC accepts keys of any length, so this cannot fail.
    let mac = <Hmac<Sha256> as Mac>::new_from_slice(secret).ok();
    mac.map_or([0; SEED_LEN], |mac| key_from_mac(mac, seed))
}

fn key_from_mac(mut mac: Hmac<Sha256>, seed: &[u8]) -> [u8; SEED_LEN] {
    mac.update(seed);
    let tag = mac.finalize().into_bytes();
    let mut key = [0; SEED_LEN];
    key.copy_from_slice(&tag[..SEED_LEN]);
    key
}

/// Server timing and security parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ServerConfig {
    /// S3: a non-default session without requests falls back to default after this.
    pub s3: Duration,
    /// P2 server max, reported in the 0x10 response (1 ms resolution).
    pub p2: Duration,
    /// P2* server max, reported in the 0x10 response (10 ms resolution).
    pub p2_star: Duration,
    /// Interval between repeated 0x78 responses while a routine runs (below P2*).
    pub pending_interval: Duration,
    /// How often the backend is asked whether a running calibration is done.
    pub pending_check: Duration,
    /// Wrong keys in a row before SecurityAccess locks.
    pub max_attempts: u8,
    /// How long SecurityAccess stays locked after `max_attempts` wrong keys.
    pub lockout: Duration,
}

impl Default for ServerConfig {
    /// DESIGN.md values: S3 5 s, P2 50 ms, P2* 5000 ms, 3 attempts, 10 s lock.
    fn default() -> Self {
        ServerConfig {
            s3: Duration::from_secs(5),
            p2: Duration::from_millis(50),
            p2_star: Duration::from_millis(5000),
            pending_interval: Duration::from_millis(2000),
            pending_check: Duration::from_millis(10),
            max_attempts: 3,
            lockout: Duration::from_secs(10),
        }
    }
}

/// A routine answered 0x78 and still owes its final response.
#[derive(Clone, Copy, Debug)]
struct Pending {
    next_pending_response: Instant,
    next_check: Instant,
}

/// The UDS server state machine.
pub struct Server<B: Backend, R: SeedSource> {
    backend: B,
    seeds: R,
    mac: Hmac<Sha256>,
    cfg: ServerConfig,
    session: Session,
    s3_deadline: Option<Instant>,
    unlocked: bool,
    seed: Option<[u8; SEED_LEN]>,
    failed_attempts: u8,
    locked_until: Option<Instant>,
    pending: Option<Pending>,
    last_outcome: Option<Outcome>,
}

impl<B: Backend, R: SeedSource> Server<B, R> {
    /// A server in the default session, locked. `secret` is the vehicle secret the
    /// SecurityAccess key is derived from (any length).
    pub fn new(backend: B, seeds: R, secret: &[u8], cfg: ServerConfig) -> Self {
        // HMAC accepts keys of any length; the fallback is unreachable.
        let mac = <Hmac<Sha256> as Mac>::new_from_slice(secret)
            .unwrap_or_else(|_| <Hmac<Sha256> as Mac>::new(&Default::default()));
        Server {
            backend,
            seeds,
            mac,
            cfg,
            session: Session::Default,
            s3_deadline: None,
            unlocked: false,
            seed: None,
            failed_attempts: 0,
            locked_until: None,
            pending: None,
            last_outcome: None,
        }
    }

    /// Restores SecurityAccess state kept across a restart: `failed_attempts` wrong keys so
    /// far, and locked for `locked_for` from `now` (ISO 14229-1: the delay timer applies
    /// after power-up too). Values beyond the configuration are clamped to it.
    pub fn restore_security(
        &mut self,
        failed_attempts: u8,
        locked_for: Option<Duration>,
        now: Instant,
    ) {
        self.failed_attempts = failed_attempts.min(self.cfg.max_attempts.saturating_sub(1));
        self.locked_until =
            locked_for.filter(|d| !d.is_zero()).map(|d| now + d.min(self.cfg.lockout));
    }

    /// The backend.
    pub fn backend(&self) -> &B {
        &self.backend
    }

    /// The backend, mutably.
    pub fn backend_mut(&mut self) -> &mut B {
        &mut self.backend
    }

    /// The active session.
    pub fn session(&self) -> Session {
        self.session
    }

    /// True once a correct key was sent in this session.
    pub fn is_unlocked(&self) -> bool {
        self.unlocked
    }

    /// True while a routine owes its final response.
    pub fn is_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Handles one request; returns the response to send, `None` when there is none
    /// (empty request, or a suppressed positive response).
    pub fn handle(&mut self, request: &[u8], now: Instant) -> Option<Response> {
        let &service = request.first()?;
        self.expire(now);
        if self.pending.is_some() {
            // One request at a time: the running routine still owes its answer.
            return Some(negative(service, Nrc::BusyRepeatRequest));
        }
        if self.session != Session::Default {
            self.s3_deadline = Some(now + self.cfg.s3);
        }
        let result = match service {
            sid::DIAGNOSTIC_SESSION_CONTROL => self.session_control(request, now),
            sid::TESTER_PRESENT => tester_present(request),
            sid::SECURITY_ACCESS => self.security_access(request, now),
            sid::READ_DATA_BY_IDENTIFIER => self.read_data(request),
            sid::ROUTINE_CONTROL => self.routine_control(request, now),
            _ => Err(Nrc::ServiceNotSupported),
        };
        match result {
            Ok(response) => response,
            Err(nrc) => Some(negative(service, nrc)),
        }
    }

    /// Runs the timers: S3 session timeout, security lockout expiry, and a pending
    /// routine (repeated 0x78, then the final response once the backend is done).
    /// Returns a response to send, if one is due.
    pub fn poll(&mut self, now: Instant) -> Option<Response> {
        self.expire(now);
        let pending = self.pending?;
        if now >= pending.next_check {
            if let Some(outcome) = self.backend.calibration_finished() {
                self.pending = None;
                self.last_outcome = Some(outcome);
                self.restart_s3(now);
                // After a 0x78 the final positive response is always sent.
                return Some(routine_response(0x01, rid::START_CALIBRATION, Some(&outcome)));
            }
            if let Some(p) = &mut self.pending {
                p.next_check = now + self.cfg.pending_check;
            }
        }
        if now >= pending.next_pending_response {
            if let Some(p) = &mut self.pending {
                p.next_pending_response = now + self.cfg.pending_interval;
            }
            return Some(negative(sid::ROUTINE_CONTROL, Nrc::ResponsePending));
        }
        None
    }

    /// When [`Server::poll`] next has something to do.
    pub fn poll_at(&self) -> Option<Instant> {
        let pending = self.pending.map(|p| p.next_check.min(p.next_pending_response));
        // S3 is stopped while a routine runs (ISO 14229-2: S3 restarts after the response).
        let s3 = if self.pending.is_some() { None } else { self.s3_deadline };
        [pending, s3, self.locked_until].into_iter().flatten().min()
    }

    fn restart_s3(&mut self, now: Instant) {
        if self.session != Session::Default {
            self.s3_deadline = Some(now + self.cfg.s3);
        }
    }

    /// S3 fallback to the default session (relocking) and lockout expiry.
    fn expire(&mut self, now: Instant) {
        if self.pending.is_none() && self.s3_deadline.is_some_and(|d| now >= d) {
            self.enter_session(Session::Default);
        }
        if self.locked_until.is_some_and(|t| now >= t) {
            self.locked_until = None;
        }
    }

    fn enter_session(&mut self, session: Session) {
        // Every session transition relocks security (ISO 14229-1 9.2.1).
        self.session = session;
        self.unlocked = false;
        self.seed = None;
        self.s3_deadline = None;
    }

    fn session_control(&mut self, req: &[u8], now: Instant) -> Result<Option<Response>, Nrc> {
        let (sub, suppress) = sub_function(req, 2)?;
        let session = match sub {
            0x01 => Session::Default,
            0x03 => Session::Extended,
            _ => return Err(Nrc::SubFunctionNotSupported),
        };
        exact_len(req, 2)?;
        self.enter_session(session);
        self.restart_s3(now);
        if suppress {
            return Ok(None);
        }
        let p2 = u16::try_from(self.cfg.p2.as_millis()).unwrap_or(u16::MAX);
        let p2_star = u16::try_from(self.cfg.p2_star.as_millis() / 10).unwrap_or(u16::MAX);
        let mut r = positive(sid::DIAGNOSTIC_SESSION_CONTROL);
        push(&mut r, &[sub]);
        push(&mut r, &p2.to_be_bytes());
        push(&mut r, &p2_star.to_be_bytes());
        Ok(Some(r))
    }

    fn security_access(&mut self, req: &[u8], now: Instant) -> Result<Option<Response>, Nrc> {
        if self.session == Session::Default {
            return Err(Nrc::ServiceNotSupportedInActiveSession);
        }
        let (sub, suppress) = sub_function(req, 2)?;
        match sub {
            0x01 => {
                exact_len(req, 2)?;
                if self.locked_until.is_some_and(|t| now < t) {
                    return Err(Nrc::RequiredTimeDelayNotExpired);
                }
                // Already unlocked: the seed is all zeros (ISO 14229-1 9.4.1).
                let mut seed = [0; SEED_LEN];
                if !self.unlocked {
                    self.seeds.fill_seed(&mut seed);
                    self.seed = Some(seed);
                }
                if suppress {
                    return Ok(None);
                }
                let mut r = positive(sid::SECURITY_ACCESS);
                push(&mut r, &[sub]);
                push(&mut r, &seed);
                Ok(Some(r))
            }
            0x02 => {
                exact_len(req, 2 + SEED_LEN)?;
                let seed = self.seed.take().ok_or(Nrc::RequestSequenceError)?;
                let expected = key_from_mac(self.mac.clone(), &seed);
                if !constant_time_eq(&expected, &req[2..]) {
                    self.failed_attempts = self.failed_attempts.saturating_add(1);
                    if self.failed_attempts >= self.cfg.max_attempts {
                        self.failed_attempts = 0;
                        self.locked_until = Some(now + self.cfg.lockout);
                        // Kept before the answer: a restart right after it still locks.
                        self.backend.security_changed(0, Some(self.cfg.lockout));
                        return Err(Nrc::ExceededNumberOfAttempts);
                    }
                    self.backend.security_changed(self.failed_attempts, None);
                    return Err(Nrc::InvalidKey);
                }
                if self.failed_attempts > 0 {
                    self.backend.security_changed(0, None);
                }
                self.failed_attempts = 0;
                self.unlocked = true;
                if suppress {
                    return Ok(None);
                }
                let mut r = positive(sid::SECURITY_ACCESS);
                push(&mut r, &[sub]);
                Ok(Some(r))
            }
            _ => Err(Nrc::SubFunctionNotSupported),
        }
    }

    fn read_data(&mut self, req: &[u8]) -> Result<Option<Response>, Nrc> {
        let ids = &req[1..];
        if ids.is_empty() || !ids.len().is_multiple_of(2) || ids.len() / 2 > MAX_DIDS_PER_REQUEST {
            return Err(Nrc::IncorrectMessageLengthOrInvalidFormat);
        }
        let sensors = self.backend.sensors();
        let known = |d: u16| served(&sensors, d);
        let dids = ids.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]]));
        if !dids.clone().any(known) {
            return Err(Nrc::RequestOutOfRange);
        }
        let mut r = positive(sid::READ_DATA_BY_IDENTIFIER);
        // Unsupported DIDs among supported ones are left out (ISO 14229-1 10.2.2).
        for d in dids.filter(|&d| known(d)) {
            let mut buf = [0u8; MAX_RECORD];
            let n = self.encode_did(d, &sensors, &mut buf)?;
            if r.len() + 2 + n > MAX_RESPONSE {
                return Err(Nrc::ResponseTooLong);
            }
            push(&mut r, &d.to_be_bytes());
            push(&mut r, &buf[..n]);
        }
        Ok(Some(r))
    }

    fn encode_did(&self, d: u16, sensors: &SensorTable, buf: &mut [u8]) -> Result<usize, Nrc> {
        let intrinsics = did::sensor_index(d, did::SENSOR_INTRINSICS);
        let extrinsic = did::sensor_index(d, did::SENSOR_EXTRINSIC);
        let n = match d {
            did::STATE => self.backend.state().emit(buf),
            did::INTRINSICS => self.backend.intrinsics().and_then(|i| i.emit(buf)),
            did::EXTRINSIC => self.backend.extrinsic().and_then(|e| e.emit(buf)),
            did::QUALITY => self.backend.quality().and_then(|q| q.emit(buf)),
            did::SENSORS => sensors.emit(buf),
            _ if intrinsics.is_some() => {
                intrinsics.and_then(|i| self.backend.sensor_intrinsics(i)).and_then(|r| r.emit(buf))
            }
            _ => extrinsic.and_then(|i| self.backend.sensor_extrinsic(i)).and_then(|r| r.emit(buf)),
        };
        n.ok_or(Nrc::ConditionsNotCorrect)
    }

    fn routine_control(&mut self, req: &[u8], now: Instant) -> Result<Option<Response>, Nrc> {
        if self.session == Session::Default {
            return Err(Nrc::ServiceNotSupportedInActiveSession);
        }
        let (sub, suppress) = sub_function(req, 4)?;
        if sub != 0x01 && sub != 0x03 {
            return Err(Nrc::SubFunctionNotSupported);
        }
        let routine = u16::from_be_bytes([req[2], req[3]]);
        if routine != rid::START_CALIBRATION && routine != rid::ROLLBACK {
            return Err(Nrc::RequestOutOfRange);
        }
        if !self.unlocked {
            return Err(Nrc::SecurityAccessDenied);
        }
        exact_len(req, 4)?;
        match (routine, sub) {
            (rid::START_CALIBRATION, 0x01) => {
                self.backend.start_calibration().map_err(|_| Nrc::ConditionsNotCorrect)?;
                self.pending = Some(Pending {
                    next_pending_response: now + self.cfg.pending_interval,
                    next_check: now + self.cfg.pending_check,
                });
                Ok(Some(negative(sid::ROUTINE_CONTROL, Nrc::ResponsePending)))
            }
            (rid::START_CALIBRATION, _) => {
                let outcome = self.last_outcome.ok_or(Nrc::RequestSequenceError)?;
                Ok((!suppress).then(|| routine_response(sub, routine, Some(&outcome))))
            }
            (_, 0x01) => {
                let generation = self.backend.rollback().map_err(|_| Nrc::ConditionsNotCorrect)?;
                let mut r = routine_response(sub, routine, None);
                push(&mut r, &generation.to_be_bytes());
                Ok((!suppress).then_some(r))
            }
            // Roll back has no results to request.
            _ => Err(Nrc::SubFunctionNotSupported),
        }
    }
}

fn tester_present(req: &[u8]) -> Result<Option<Response>, Nrc> {
    let (sub, suppress) = sub_function(req, 2)?;
    if sub != 0x00 {
        return Err(Nrc::SubFunctionNotSupported);
    }
    exact_len(req, 2)?;
    if suppress {
        return Ok(None);
    }
    let mut r = positive(sid::TESTER_PRESENT);
    push(&mut r, &[0x00]);
    Ok(Some(r))
}

fn routine_response(sub: u8, routine: u16, outcome: Option<&Outcome>) -> Response {
    let mut r = positive(sid::ROUTINE_CONTROL);
    push(&mut r, &[sub]);
    push(&mut r, &routine.to_be_bytes());
    if let Some(o) = outcome {
        let mut buf = [0; Outcome::LEN];
        let n = o.emit(&mut buf).unwrap_or(0);
        push(&mut r, &buf[..n]);
    }
    r
}

fn positive(service: u8) -> Response {
    let mut r = Response::new();
    push(&mut r, &[service.wrapping_add(sid::POSITIVE_OFFSET)]);
    r
}

/// The negative response `7F SID NRC`.
pub fn negative(service: u8, nrc: Nrc) -> Response {
    let mut r = Response::new();
    push(&mut r, &[sid::NEGATIVE_RESPONSE, service, nrc as u8]);
    r
}

/// Whether the server answers DID `d` for a vehicle with `sensors`: the fixed DIDs, the
/// sensor table, intrinsics of each camera and the extrinsic of each sensor in the table.
fn served(sensors: &SensorTable, d: u16) -> bool {
    let fixed = (did::STATE..=did::QUALITY).contains(&d) || d == did::SENSORS;
    let camera = did::sensor_index(d, did::SENSOR_INTRINSICS)
        .is_some_and(|i| sensors.kind(i) == Some(SensorKind::Camera));
    let sensor =
        did::sensor_index(d, did::SENSOR_EXTRINSIC).is_some_and(|i| sensors.kind(i).is_some());
    fixed || camera || sensor
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}
