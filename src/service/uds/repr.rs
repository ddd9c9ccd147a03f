//! Requests and responses of the service as values (`RequestRepr`, `ResponseRepr`): what a
//! client builds and what logs and fuzzing parse, without the server's session state.

use super::records::*;

/// A request the server understands, as the client builds it. Parsing is
/// context-free (no session or security): the server itself checks requests in the
/// ISO 14229 NRC order, this is for clients, logs and fuzzing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RequestRepr {
    SessionControl {
        session: Session,
        suppress: bool,
    },
    TesterPresent {
        suppress: bool,
    },
    RequestSeed {
        suppress: bool,
    },
    SendKey {
        key: [u8; SEED_LEN],
        suppress: bool,
    },
    ReadData {
        dids: heapless::Vec<u16, MAX_DIDS_PER_REQUEST>,
    },
    /// `sub`: 0x01 start, 0x03 request results.
    RoutineControl {
        sub: u8,
        routine: u16,
        suppress: bool,
    },
}

impl RequestRepr {
    /// Parses a request; the error is the NRC a context-free server would answer.
    pub fn parse(bytes: &[u8]) -> Result<Self, Nrc> {
        let &service = bytes.first().ok_or(Nrc::IncorrectMessageLengthOrInvalidFormat)?;
        let sub = |min| sub_function(bytes, min);
        let repr = match service {
            sid::DIAGNOSTIC_SESSION_CONTROL => {
                let (s, suppress) = sub(2)?;
                let session = match s {
                    0x01 => Session::Default,
                    0x03 => Session::Extended,
                    _ => return Err(Nrc::SubFunctionNotSupported),
                };
                exact_len(bytes, 2)?;
                RequestRepr::SessionControl { session, suppress }
            }
            sid::TESTER_PRESENT => {
                let (s, suppress) = sub(2)?;
                if s != 0 {
                    return Err(Nrc::SubFunctionNotSupported);
                }
                exact_len(bytes, 2)?;
                RequestRepr::TesterPresent { suppress }
            }
            sid::SECURITY_ACCESS => match sub(2)? {
                (0x01, suppress) => {
                    exact_len(bytes, 2)?;
                    RequestRepr::RequestSeed { suppress }
                }
                (0x02, suppress) => {
                    exact_len(bytes, 2 + SEED_LEN)?;
                    let mut key = [0; SEED_LEN];
                    key.copy_from_slice(&bytes[2..]);
                    RequestRepr::SendKey { key, suppress }
                }
                _ => return Err(Nrc::SubFunctionNotSupported),
            },
            sid::READ_DATA_BY_IDENTIFIER => {
                let ids = &bytes[1..];
                if ids.is_empty()
                    || !ids.len().is_multiple_of(2)
                    || ids.len() / 2 > MAX_DIDS_PER_REQUEST
                {
                    return Err(Nrc::IncorrectMessageLengthOrInvalidFormat);
                }
                let mut dids = heapless::Vec::new();
                for c in ids.chunks_exact(2) {
                    // At most MAX_DIDS_PER_REQUEST, checked above.
                    let _ = dids.push(u16::from_be_bytes([c[0], c[1]]));
                }
                RequestRepr::ReadData { dids }
            }
            sid::ROUTINE_CONTROL => {
                let (s, suppress) = sub(4)?;
                if s != 0x01 && s != 0x03 {
                    return Err(Nrc::SubFunctionNotSupported);
                }
                exact_len(bytes, 4)?;
                let routine = u16::from_be_bytes([bytes[2], bytes[3]]);
                RequestRepr::RoutineControl { sub: s, routine, suppress }
            }
            _ => return Err(Nrc::ServiceNotSupported),
        };
        Ok(repr)
    }

    /// Encoded length.
    pub fn buffer_len(&self) -> usize {
        match self {
            RequestRepr::SessionControl { .. }
            | RequestRepr::TesterPresent { .. }
            | RequestRepr::RequestSeed { .. } => 2,
            RequestRepr::SendKey { .. } => 2 + SEED_LEN,
            RequestRepr::ReadData { dids } => 1 + 2 * dids.len(),
            RequestRepr::RoutineControl { .. } => 4,
        }
    }

    /// Encodes into `buf`; returns the bytes written, `None` if `buf` is too short.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let spr = |suppress: bool| if suppress { SUPPRESS_POSITIVE_RESPONSE } else { 0 };
        let mut w = Writer::new(buf);
        match self {
            RequestRepr::SessionControl { session, suppress } => {
                w.put(&[sid::DIAGNOSTIC_SESSION_CONTROL, *session as u8 | spr(*suppress)])?
            }
            RequestRepr::TesterPresent { suppress } => {
                w.put(&[sid::TESTER_PRESENT, spr(*suppress)])?
            }
            RequestRepr::RequestSeed { suppress } => {
                w.put(&[sid::SECURITY_ACCESS, 0x01 | spr(*suppress)])?
            }
            RequestRepr::SendKey { key, suppress } => {
                w.put(&[sid::SECURITY_ACCESS, 0x02 | spr(*suppress)])?;
                w.put(key)?;
            }
            RequestRepr::ReadData { dids } => {
                w.put(&[sid::READ_DATA_BY_IDENTIFIER])?;
                for d in dids {
                    w.put(&d.to_be_bytes())?;
                }
            }
            RequestRepr::RoutineControl { sub, routine, suppress } => {
                w.put(&[sid::ROUTINE_CONTROL, (sub & 0x7F) | spr(*suppress)])?;
                w.put(&routine.to_be_bytes())?;
            }
        }
        Some(w.len())
    }
}

/// A response as the client sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResponseRepr<'a> {
    /// Positive response to `service`; `data` follows the response SID.
    Positive { service: u8, data: &'a [u8] },
    /// Negative response to `service` (the raw NRC byte).
    Negative { service: u8, nrc: u8 },
}

impl<'a> ResponseRepr<'a> {
    /// Parses a response message; `None` if it is empty, a truncated negative
    /// response, or not a response SID.
    pub fn parse(bytes: &'a [u8]) -> Option<Self> {
        match *bytes {
            [sid::NEGATIVE_RESPONSE, service, nrc] => Some(ResponseRepr::Negative { service, nrc }),
            [sid::NEGATIVE_RESPONSE, ..] => None,
            [first, ..] if first & sid::POSITIVE_OFFSET != 0 => Some(ResponseRepr::Positive {
                service: first - sid::POSITIVE_OFFSET,
                data: &bytes[1..],
            }),
            _ => None,
        }
    }
}
