//! The trigger state machine (pure: time passed in, no I/O): decides when the vehicle is
//! in the room and still, starts one capture per visit, and reports the daemon's state.
//!
//! ```text
//! idle ──boards≥N──► room seen ──still──► settling ──still for settle_s──► capturing
//!  ▲                   │ ▲                   │ moved                          │ captured
//!  │                   │ └───────────────────┘                                ▼
//!  └──── room left ◄── accepted / rejected / error (latched) ◄──outcome── solving
//! ```
//!
//! "Room left" means fewer than N boards for `leave_s`, so a single missed detection does
//! not end a visit. In manual mode the room and motion are tracked for the state report
//! but only [`Trigger::request`] starts a capture; a request is also honoured in auto mode
//! (the service tool's RoutineControl start) and overrides the latch.

use crate::service::uds::DaemonState;

/// Auto: room seen + vehicle still; manual: only on request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    Auto,
    Manual,
}

/// Trigger parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriggerConfig {
    pub mode: Mode,
    /// Boards the cheap detection must see for the room to count as seen.
    pub min_boards: usize,
    /// Seconds the vehicle must stay still before capturing.
    pub settle_s: f64,
    /// Sweep-to-sweep motion (m) below which the vehicle counts as still.
    pub still_m: f32,
    /// Seconds without enough boards before the room counts as left.
    pub leave_s: f64,
}

impl Default for TriggerConfig {
    fn default() -> Self {
        TriggerConfig {
            mode: Mode::Auto,
            min_boards: 1,
            settle_s: 2.0,
            still_m: 0.01,
            leave_s: 3.0,
        }
    }
}

/// Where the trigger is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Phase {
    Idle,
    RoomSeen,
    /// Still since `since` (seconds).
    Settling {
        since: f64,
    },
    Capturing,
    Solving,
    /// A run ended; latched until the room is left (or a request).
    Done(Verdict),
}

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Accepted,
    Rejected,
    Error,
}

/// What the daemon must do after an event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Nothing new.
    None,
    /// Start capturing frames and sweeps for a run.
    Capture,
}

/// The trigger.
#[derive(Clone, Debug)]
pub struct Trigger {
    cfg: TriggerConfig,
    phase: Phase,
    /// Whether the last detection pass saw the room, and since when it has not.
    room: bool,
    absent_since: Option<f64>,
}

impl Trigger {
    /// An idle trigger.
    pub fn new(cfg: TriggerConfig) -> Self {
        Trigger { cfg, phase: Phase::Idle, room: false, absent_since: None }
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The state as the service reports it (DID 0xC001).
    pub fn state(&self) -> DaemonState {
        match self.phase {
            Phase::Idle => DaemonState::Idle,
            Phase::RoomSeen | Phase::Settling { .. } => DaemonState::RoomSeen,
            Phase::Capturing => DaemonState::Capturing,
            Phase::Solving => DaemonState::Solving,
            Phase::Done(Verdict::Accepted) => DaemonState::Accepted,
            Phase::Done(Verdict::Rejected) => DaemonState::Rejected,
            Phase::Done(Verdict::Error) => DaemonState::Error,
        }
    }

    /// Result of a cheap detection pass at `now`: `boards` boards seen.
    pub fn on_boards(&mut self, now: f64, boards: usize) -> Action {
        self.on_room(now, boards >= self.cfg.min_boards)
    }

    /// Result of a cheap detection pass at `now` over every watched camera: whether each
    /// saw its boards (a rig's cameras may each need their own count).
    pub fn on_room(&mut self, now: f64, seen: bool) -> Action {
        self.room = seen;
        if seen {
            self.absent_since = None;
            if self.phase == Phase::Idle {
                self.phase = Phase::RoomSeen;
            }
            return Action::None;
        }
        let since = *self.absent_since.get_or_insert(now);
        let left = now - since + 1e-9 >= self.cfg.leave_s;
        if left {
            match self.phase {
                Phase::RoomSeen | Phase::Settling { .. } | Phase::Done(_) => {
                    self.phase = Phase::Idle
                }
                // A run in progress finishes; the latch then waits for the next pass.
                Phase::Idle | Phase::Capturing | Phase::Solving => {}
            }
        }
        Action::None
    }

    /// Sweep-to-sweep motion (m) measured at `now`.
    pub fn on_motion(&mut self, now: f64, motion_m: f32) -> Action {
        let still = motion_m < self.cfg.still_m;
        match self.phase {
            Phase::RoomSeen if still => {
                self.phase = Phase::Settling { since: now };
                self.settled(now)
            }
            Phase::Settling { .. } if !still => {
                self.phase = Phase::RoomSeen;
                Action::None
            }
            Phase::Settling { .. } => self.settled(now),
            _ => Action::None,
        }
    }

    /// A run was requested (library call or service tool). Refused (`false`) while a run
    /// is in progress.
    pub fn request(&mut self) -> (bool, Action) {
        match self.phase {
            Phase::Capturing | Phase::Solving => (false, Action::None),
            _ => {
                self.phase = Phase::Capturing;
                (true, Action::Capture)
            }
        }
    }

    /// The capture finished; solving starts.
    pub fn on_captured(&mut self) {
        if self.phase == Phase::Capturing {
            self.phase = Phase::Solving;
        }
    }

    /// The run ended (a failed capture counts as [`Verdict::Error`]).
    pub fn on_outcome(&mut self, verdict: Verdict) {
        if matches!(self.phase, Phase::Capturing | Phase::Solving) {
            self.phase = Phase::Done(verdict);
        }
    }

    fn settled(&mut self, now: f64) -> Action {
        let Phase::Settling { since } = self.phase else {
            return Action::None;
        };
        // The tolerance absorbs rounding in times built from sums of sample intervals.
        if self.cfg.mode == Mode::Auto && now - since + 1e-9 >= self.cfg.settle_s {
            self.phase = Phase::Capturing;
            return Action::Capture;
        }
        Action::None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trig(mode: Mode) -> Trigger {
        Trigger::new(TriggerConfig {
            mode,
            min_boards: 4,
            settle_s: 2.0,
            still_m: 0.01,
            leave_s: 3.0,
        })
    }

    /// Drives an auto trigger to the capture.
    fn to_capture(t: &mut Trigger) -> f64 {
        t.on_boards(0.0, 4);
        t.on_motion(0.1, 0.001);
        assert_eq!(t.on_motion(2.1, 0.001), Action::Capture);
        2.1
    }

    #[test]
    fn idle_stays_idle_with_too_few_boards() {
        let mut t = trig(Mode::Auto);
        t.on_boards(0.0, 3);
        assert_eq!(t.phase(), Phase::Idle);
        assert_eq!(t.on_motion(1.0, 0.0), Action::None);
        assert_eq!(t.state(), DaemonState::Idle);
    }

    #[test]
    fn idle_to_room_seen_to_settling() {
        let mut t = trig(Mode::Auto);
        t.on_boards(0.0, 4);
        assert_eq!(t.phase(), Phase::RoomSeen);
        assert_eq!(t.state(), DaemonState::RoomSeen);
        assert_eq!(t.on_motion(0.5, 0.2), Action::None);
        assert_eq!(t.phase(), Phase::RoomSeen, "moving: not settling");
        t.on_motion(0.6, 0.005);
        assert_eq!(t.phase(), Phase::Settling { since: 0.6 });
    }

    #[test]
    fn motion_restarts_the_settle_time() {
        let mut t = trig(Mode::Auto);
        t.on_boards(0.0, 4);
        t.on_motion(0.0, 0.0);
        assert_eq!(t.on_motion(1.9, 0.0), Action::None);
        t.on_motion(2.0, 0.05);
        assert_eq!(t.phase(), Phase::RoomSeen);
        t.on_motion(2.1, 0.0);
        assert_eq!(t.on_motion(4.0, 0.0), Action::None, "only 1.9 s still");
        assert_eq!(t.on_motion(4.1, 0.0), Action::Capture);
        assert_eq!(t.state(), DaemonState::Capturing);
    }

    #[test]
    fn capturing_solving_and_verdicts() {
        for (v, s) in [
            (Verdict::Accepted, DaemonState::Accepted),
            (Verdict::Rejected, DaemonState::Rejected),
            (Verdict::Error, DaemonState::Error),
        ] {
            let mut t = trig(Mode::Auto);
            to_capture(&mut t);
            t.on_captured();
            assert_eq!(t.state(), DaemonState::Solving);
            t.on_outcome(v);
            assert_eq!(t.state(), s);
        }
    }

    #[test]
    fn one_run_per_visit_until_the_room_is_left() {
        let mut t = trig(Mode::Auto);
        let now = to_capture(&mut t);
        t.on_captured();
        t.on_outcome(Verdict::Accepted);
        // Still in the room and still: latched.
        t.on_boards(now + 1.0, 6);
        assert_eq!(t.on_motion(now + 10.0, 0.0), Action::None);
        assert_eq!(t.phase(), Phase::Done(Verdict::Accepted));
        // One missed detection is not leaving.
        t.on_boards(now + 11.0, 0);
        t.on_boards(now + 12.0, 4);
        t.on_boards(now + 13.0, 0);
        t.on_boards(now + 15.9, 0);
        assert_eq!(t.phase(), Phase::Done(Verdict::Accepted));
        t.on_boards(now + 16.0, 0);
        assert_eq!(t.phase(), Phase::Idle, "3 s without the room");
        // Next visit runs again.
        t.on_boards(now + 20.0, 4);
        t.on_motion(now + 20.0, 0.0);
        assert_eq!(t.on_motion(now + 22.0, 0.0), Action::Capture);
    }

    #[test]
    fn leaving_while_settling_goes_idle_but_a_run_finishes() {
        let mut t = trig(Mode::Auto);
        t.on_boards(0.0, 4);
        t.on_motion(0.0, 0.0);
        t.on_boards(1.0, 0);
        t.on_boards(4.0, 0);
        assert_eq!(t.phase(), Phase::Idle);
        let mut t = trig(Mode::Auto);
        to_capture(&mut t);
        t.on_boards(3.0, 0);
        t.on_boards(9.0, 0);
        assert_eq!(t.phase(), Phase::Capturing);
    }

    #[test]
    fn manual_mode_runs_only_on_request() {
        let mut t = trig(Mode::Manual);
        t.on_boards(0.0, 4);
        t.on_motion(0.0, 0.0);
        assert_eq!(t.on_motion(60.0, 0.0), Action::None);
        assert_eq!(t.state(), DaemonState::RoomSeen);
        assert_eq!(t.request(), (true, Action::Capture));
        assert_eq!(t.request(), (false, Action::None), "busy");
        t.on_captured();
        assert_eq!(t.request(), (false, Action::None), "busy solving");
        t.on_outcome(Verdict::Rejected);
        // A request overrides the latch; idle manual requests work too.
        assert_eq!(t.request(), (true, Action::Capture));
        let mut idle = trig(Mode::Manual);
        assert_eq!(idle.request(), (true, Action::Capture));
    }

    #[test]
    fn stray_events_do_not_move_the_phase() {
        let mut t = trig(Mode::Auto);
        t.on_captured();
        t.on_outcome(Verdict::Accepted);
        assert_eq!(t.phase(), Phase::Idle);
    }
}
