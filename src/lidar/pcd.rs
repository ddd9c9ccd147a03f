//! PCD (Point Cloud Library) files: reader and writer.
//!
//! Reads `ascii`, `binary` and `binary_compressed` (LZF, see [`super::lzf`]) data with any
//! field order, any of the PCD scalar types (F4 F8, I1 I2 I4 I8, U1 U2 U4 U8) and any
//! `COUNT`. It takes `x y z` and, when present, intensity (`intensity`, `i`), ring
//! (`ring`, `channel`, `laser_id`) and time (`time`, `timestamp`, `time_stamp`, `t`);
//! other fields are skipped. Points with a non-finite coordinate and points at exactly
//! the origin (how drivers mark "no return") are dropped.
//!
//! Writes the cloud format of DESIGN.md "Decoded clouds": fields `x y z intensity ring`
//! (F4 F4 F4 F4 U2), to a temporary file renamed into place so readers never see half a
//! file.
//!
//! [`PcdReader`] keeps its file and decompression buffers between calls, so reading a
//! cloud of a size seen before into a reused `Vec<Point>` allocates nothing.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

use super::{lzf, Point};

/// Most fields a PCD header may declare (the header is parsed without allocating).
pub const MAX_FIELDS: usize = 64;
/// Most points a PCD file may declare (1 Mi), checked from the header before anything is
/// sized from it: a 128-beam sweep holds about 0.3 M points. With [`MAX_DATA_BYTES`] this
/// keeps calibrating from a cloud within the memory budget of docs/limits.md: a point
/// takes 32 B, and a calibration's work on a cloud about 230 B a point in all.
pub const MAX_POINTS: usize = 1 << 20;
/// Most bytes a PCD file may hold, and most its data may take once decompressed
/// (`POINTS × record`, from the header, before inflating).
pub const MAX_DATA_BYTES: usize = 64 << 20;
/// Room for the header (and comments) in a file of [`MAX_DATA_BYTES`] of data.
const MAX_HEADER_BYTES: usize = 1 << 16;

/// Data section encoding of a PCD file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PcdFormat {
    /// One point per text line.
    Ascii,
    /// Packed little-endian records, one per point.
    Binary,
    /// Field-by-field arrays, LZF-compressed as a whole.
    BinaryCompressed,
}

impl PcdFormat {
    /// The name used on the header's `DATA` line.
    pub fn as_str(self) -> &'static str {
        match self {
            PcdFormat::Ascii => "ascii",
            PcdFormat::Binary => "binary",
            PcdFormat::BinaryCompressed => "binary_compressed",
        }
    }
}

impl core::fmt::Display for PcdFormat {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl core::str::FromStr for PcdFormat {
    type Err = String;

    /// Parses a `DATA` name (any case), e.g. for a command-line option.
    fn from_str(s: &str) -> Result<Self, String> {
        [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed]
            .into_iter()
            .find(|f| f.as_str().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown PCD format `{s}` (ascii, binary, binary_compressed)"))
    }
}

/// What a successful read found besides the points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PcdInfo {
    /// Data encoding.
    pub format: PcdFormat,
    /// `POINTS` of the header (or `WIDTH × HEIGHT`).
    pub declared_points: usize,
    /// `WIDTH` and `HEIGHT` of the header.
    pub width: usize,
    pub height: usize,
    /// Points dropped as NaN/infinite or all-zero.
    pub skipped: usize,
    /// Which optional fields the file carries.
    pub has_intensity: bool,
    pub has_ring: bool,
    pub has_time: bool,
}

/// Why a PCD file could not be read or written. Every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum PcdError {
    #[error("{file}: {source}")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: bad PCD header, line {line}: {problem}")]
    Header { file: String, line: usize, problem: String },
    #[error("{file}: PCD has no `{field}` field")]
    MissingField { file: String, field: &'static str },
    #[error("{file}: PCD data truncated: {what} needs {needed} bytes, {available} present")]
    Truncated { file: String, what: &'static str, needed: u64, available: u64 },
    #[error("{file}: PCD ascii data line {line}: {problem}")]
    Ascii { file: String, line: usize, problem: String },
    #[error("{file}: PCD binary_compressed data: {problem}")]
    Compressed { file: String, problem: String },
}

/// Reads the points of the PCD file at `path`.
pub fn read(path: impl AsRef<Path>) -> Result<Vec<Point>, PcdError> {
    let mut out = Vec::new();
    PcdReader::new().read_into(path, &mut out)?;
    Ok(out)
}

/// Parses PCD file contents; `name` is used in error messages.
pub fn parse(bytes: &[u8], name: &str) -> Result<Vec<Point>, PcdError> {
    let mut out = Vec::new();
    PcdReader::new().parse_into(bytes, name, &mut out)?;
    Ok(out)
}

/// Reads the PCD file at `path` into `out` (cleared first), reusing its capacity.
/// Buffers for the file itself are fresh; keep a [`PcdReader`] to reuse those too.
pub fn read_into(path: impl AsRef<Path>, out: &mut Vec<Point>) -> Result<PcdInfo, PcdError> {
    PcdReader::new().read_into(path, out)
}

/// Writes `points` to `path` as PCD with fields `x y z intensity ring` (F4 F4 F4 F4 U2).
/// The data go to a temporary file beside `path` that is renamed over it at the end.
pub fn write(path: impl AsRef<Path>, points: &[Point], format: PcdFormat) -> Result<(), PcdError> {
    let path = path.as_ref();
    let mut bytes = Vec::new();
    encode(points, format, &mut bytes);
    write_atomically(path, &bytes).map_err(|source| PcdError::Io { file: display(path), source })
}

/// Appends the PCD encoding of `points` (fields `x y z intensity ring`) to `out`.
pub fn encode(points: &[Point], format: PcdFormat, out: &mut Vec<u8>) {
    let data = format.as_str();
    let n = points.len();
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity ring\n\
         SIZE 4 4 4 4 2\nTYPE F F F F U\nCOUNT 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    );
    out.extend_from_slice(header.as_bytes());
    match format {
        PcdFormat::Ascii => encode_ascii(points, out),
        PcdFormat::Binary => encode_binary(points, out),
        PcdFormat::BinaryCompressed => encode_compressed(points, out),
    }
}

/// Reusable PCD reader: keeps the file and decompression buffers between reads.
#[derive(Debug, Default)]
pub struct PcdReader {
    file: Vec<u8>,
    scratch: Vec<u8>,
}

impl PcdReader {
    pub fn new() -> Self {
        Self::default()
    }

    /// Reads the PCD file at `path` into `out` (cleared first). Allocates only when a
    /// buffer must grow.
    pub fn read_into(
        &mut self,
        path: impl AsRef<Path>,
        out: &mut Vec<Point>,
    ) -> Result<PcdInfo, PcdError> {
        let path = path.as_ref();
        let mut file_buf = core::mem::take(&mut self.file);
        let loaded = load(path, &mut file_buf);
        let result = match loaded {
            Ok(()) => self.parse_with(&file_buf, &Name::Path(path), out),
            Err(source) => Err(PcdError::Io { file: display(path), source }),
        };
        self.file = file_buf;
        result
    }

    /// Parses PCD file contents into `out` (cleared first); `name` is used in errors.
    pub fn parse_into(
        &mut self,
        bytes: &[u8],
        name: &str,
        out: &mut Vec<Point>,
    ) -> Result<PcdInfo, PcdError> {
        self.parse_with(bytes, &Name::Str(name), out)
    }

    fn parse_with(
        &mut self,
        bytes: &[u8],
        name: &Name<'_>,
        out: &mut Vec<Point>,
    ) -> Result<PcdInfo, PcdError> {
        out.clear();
        let header = Header::parse(bytes).map_err(|(line, problem)| PcdError::Header {
            file: name.to_string(),
            line,
            problem,
        })?;
        let layout = Layout::new(&header)
            .map_err(|field| PcdError::MissingField { file: name.to_string(), field })?;
        let data = bytes.get(header.data_start..).unwrap_or(&[]);
        let skipped = match header.format {
            PcdFormat::Ascii => read_ascii(data, &header, &layout, name, out)?,
            PcdFormat::Binary => {
                let body = sized(data, header.points, header.stride, "binary data", name)?;
                read_records(body, header.points, &layout.aos(), out)
            }
            PcdFormat::BinaryCompressed => {
                let body = decompress(data, &header, name, &mut self.scratch)?;
                read_records(body, header.points, &layout.soa(&header), out)
            }
        };
        Ok(PcdInfo {
            format: header.format,
            declared_points: header.points,
            width: header.width,
            height: header.height,
            skipped,
            has_intensity: layout.intensity.is_some(),
            has_ring: layout.ring.is_some(),
            has_time: layout.time.is_some(),
        })
    }
}

/// The input's name for error messages, formatted only when an error happens.
enum Name<'a> {
    Path(&'a Path),
    Str(&'a str),
}

impl core::fmt::Display for Name<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Name::Path(p) => write!(f, "{}", p.display()),
            Name::Str(s) => f.write_str(s),
        }
    }
}

fn display(path: &Path) -> String {
    path.display().to_string()
}

/// Reads the whole file into `buf`, reusing its capacity; a file above [`MAX_DATA_BYTES`]
/// is refused before it is read.
fn load(path: &Path, buf: &mut Vec<u8>) -> std::io::Result<()> {
    let mut f = File::open(path)?;
    buf.clear();
    let len = f.metadata().map(|m| m.len() as usize).unwrap_or(0);
    if len > MAX_DATA_BYTES + MAX_HEADER_BYTES {
        return Err(std::io::Error::other(format!(
            "{len} bytes, more than the {} bytes of a PCD file roomcal reads",
            MAX_DATA_BYTES + MAX_HEADER_BYTES
        )));
    }
    buf.reserve(len.saturating_add(1));
    f.read_to_end(buf)?;
    Ok(())
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut tmp_name = path.file_name().unwrap_or_default().to_os_string();
    tmp_name.push(format!(".tmp{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let result = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

// ---------------------------------------------------------------------------------------
// Header

/// Scalar type of a field (PCD `TYPE` + `SIZE`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    F4,
    F8,
    I1,
    I2,
    I4,
    I8,
    U1,
    U2,
    U4,
    U8,
}

impl Scalar {
    fn new(kind: &str, size: usize) -> Option<Scalar> {
        let kind = match kind {
            "f" | "F" => "F",
            "i" | "I" => "I",
            "u" | "U" => "U",
            _ => return None,
        };
        Some(match (kind, size) {
            ("F", 4) => Scalar::F4,
            ("F", 8) => Scalar::F8,
            ("I", 1) => Scalar::I1,
            ("I", 2) => Scalar::I2,
            ("I", 4) => Scalar::I4,
            ("I", 8) => Scalar::I8,
            ("U", 1) => Scalar::U1,
            ("U", 2) => Scalar::U2,
            ("U", 4) => Scalar::U4,
            ("U", 8) => Scalar::U8,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I1 | Scalar::U1 => 1,
            Scalar::I2 | Scalar::U2 => 2,
            Scalar::F4 | Scalar::I4 | Scalar::U4 => 4,
            Scalar::F8 | Scalar::I8 | Scalar::U8 => 8,
        }
    }
}

/// What a field means to us.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    X,
    Y,
    Z,
    Intensity,
    Ring,
    Time,
    Other,
}

impl Role {
    fn from_name(name: &str) -> Role {
        match name {
            "x" => Role::X,
            "y" => Role::Y,
            "z" => Role::Z,
            "intensity" | "i" => Role::Intensity,
            "ring" | "channel" | "laser_id" => Role::Ring,
            "time" | "timestamp" | "time_stamp" | "t" => Role::Time,
            _ => Role::Other,
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Field {
    role: Role,
    scalar: Scalar,
    count: usize,
}

impl Field {
    fn bytes(&self) -> usize {
        self.scalar.size() * self.count
    }
}

type Fields = heapless::Vec<Field, MAX_FIELDS>;
type Tokens<T> = heapless::Vec<T, MAX_FIELDS>;

/// A parsed, validated PCD header.
#[derive(Debug)]
struct Header {
    fields: Fields,
    stride: usize,
    width: usize,
    height: usize,
    points: usize,
    format: PcdFormat,
    data_start: usize,
}

/// Header lines collected before they are combined into fields.
#[derive(Default)]
struct RawHeader<'a> {
    names: Option<Tokens<&'a str>>,
    sizes: Option<Tokens<usize>>,
    kinds: Option<Tokens<&'a str>>,
    counts: Option<Tokens<usize>>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
}

/// Largest point record we accept; real clouds have a few dozen bytes.
const MAX_STRIDE: usize = 1 << 20;

impl Header {
    /// Parses the header; errors are (line number, problem).
    fn parse(bytes: &[u8]) -> Result<Header, (usize, String)> {
        let mut raw = RawHeader::default();
        let mut pos = 0;
        let mut line_no = 0;
        while pos < bytes.len() {
            line_no += 1;
            let end =
                bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |e| pos + e);
            let next = (end + 1).min(bytes.len());
            let line = core::str::from_utf8(&bytes[pos..end])
                .map_err(|_| (line_no, "not text".to_string()))?
                .trim();
            pos = next;
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut words = line.split_ascii_whitespace();
            let key = words.next().unwrap_or_default();
            let bad = |what: &str| (line_no, format!("{what}: `{}`", truncate(line)));
            let is = |k: &str| key.eq_ignore_ascii_case(k);
            if is("VERSION") || is("VIEWPOINT") {
            } else if is("FIELDS") || is("COLUMNS") {
                raw.names = Some(collect(words, Some).ok_or_else(|| bad("FIELDS"))?);
            } else if is("SIZE") {
                raw.sizes = Some(collect(words, |w| w.parse().ok()).ok_or_else(|| bad("SIZE"))?);
            } else if is("TYPE") {
                raw.kinds = Some(collect(words, Some).ok_or_else(|| bad("TYPE"))?);
            } else if is("COUNT") {
                raw.counts = Some(collect(words, |w| w.parse().ok()).ok_or_else(|| bad("COUNT"))?);
            } else if is("WIDTH") {
                raw.width = Some(single(words).ok_or_else(|| bad("WIDTH"))?);
            } else if is("HEIGHT") {
                raw.height = Some(single(words).ok_or_else(|| bad("HEIGHT"))?);
            } else if is("POINTS") {
                raw.points = Some(single(words).ok_or_else(|| bad("POINTS"))?);
            } else if is("DATA") {
                let word = words.next().unwrap_or_default();
                let formats = [PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed];
                let Some(format) =
                    formats.into_iter().find(|f| f.as_str().eq_ignore_ascii_case(word))
                else {
                    return Err(bad("unknown DATA format"));
                };
                return raw.finish(format, pos).map_err(|p| (line_no, p));
            } else {
                return Err(bad("unknown header keyword"));
            }
        }
        Err((line_no, "no DATA line".to_string()))
    }
}

impl RawHeader<'_> {
    fn finish(self, format: PcdFormat, data_start: usize) -> Result<Header, String> {
        let names = self.names.ok_or("no FIELDS line")?;
        let sizes = self.sizes.ok_or("no SIZE line")?;
        let kinds = self.kinds.ok_or("no TYPE line")?;
        let n = names.len();
        let counts = self.counts.unwrap_or_else(|| (0..n).map(|_| 1).collect());
        if sizes.len() != n || kinds.len() != n || counts.len() != n {
            return Err(format!(
                "FIELDS has {n} entries but SIZE {}, TYPE {}, COUNT {}",
                sizes.len(),
                kinds.len(),
                counts.len()
            ));
        }
        let mut fields = Fields::new();
        let mut stride = 0usize;
        for i in 0..n {
            let scalar = Scalar::new(kinds[i], sizes[i]).ok_or_else(|| {
                format!("field `{}`: TYPE {} SIZE {}", names[i], kinds[i], sizes[i])
            })?;
            let mut role = Role::from_name(names[i]);
            if role != Role::Other && fields.iter().any(|f: &Field| f.role == role) {
                role = Role::Other; // the first field of a role wins
            }
            let field = Field { role, scalar, count: counts[i] };
            stride = stride.saturating_add(scalar.size().saturating_mul(counts[i]));
            if counts[i] == 0 {
                return Err(format!("field `{}` has COUNT 0", names[i]));
            }
            // n <= MAX_FIELDS by construction of the token lists.
            let _ = fields.push(field);
        }
        if stride > MAX_STRIDE {
            return Err(format!("point record of {stride} bytes is too large"));
        }
        let width = self.width.ok_or("no WIDTH line")?;
        let height = self.height.unwrap_or(1);
        let cells = width.checked_mul(height).ok_or("WIDTH × HEIGHT overflows")?;
        let points = self.points.unwrap_or(cells);
        if points != cells {
            return Err(format!("POINTS {points} is not WIDTH × HEIGHT = {width} × {height}"));
        }
        if points > MAX_POINTS {
            return Err(format!(
                "POINTS {points} is more than the {MAX_POINTS} points roomcal reads"
            ));
        }
        let data_bytes = points.saturating_mul(stride);
        if format != PcdFormat::Ascii && data_bytes > MAX_DATA_BYTES {
            return Err(format!(
                "POINTS × record = {points} × {stride} bytes is more than the {MAX_DATA_BYTES} \
                 bytes of data roomcal reads"
            ));
        }
        Ok(Header { fields, stride, width, height, points, format, data_start })
    }
}

/// Collects up to [`MAX_FIELDS`] parsed words; `None` if one fails, there are too many,
/// or there are none.
fn collect<'a, T>(
    words: impl Iterator<Item = &'a str>,
    parse: impl Fn(&'a str) -> Option<T>,
) -> Option<Tokens<T>> {
    let mut v = Tokens::new();
    for w in words {
        v.push(parse(w)?).ok()?;
    }
    (!v.is_empty()).then_some(v)
}

fn single<'a>(mut words: impl Iterator<Item = &'a str>) -> Option<usize> {
    let v = words.next()?.parse().ok()?;
    words.next().is_none().then_some(v)
}

fn truncate(s: &str) -> &str {
    let mut end = s.len().min(60);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

// ---------------------------------------------------------------------------------------
// Data

/// Where the fields we read sit in a point record.
struct Layout {
    stride: usize,
    x: Slot,
    y: Slot,
    z: Slot,
    intensity: Option<Slot>,
    ring: Option<Slot>,
    time: Option<Slot>,
}

/// A field's byte offset within a record, its element size, its index among the ascii
/// values of a line, and its type.
#[derive(Clone, Copy)]
struct Slot {
    offset: usize,
    bytes: usize,
    value_index: usize,
    scalar: Scalar,
}

/// A field's position in a data block: value of point `i` at `start + i * step`.
#[derive(Clone, Copy)]
struct Locator {
    start: usize,
    step: usize,
    scalar: Scalar,
}

struct Locators {
    x: Locator,
    y: Locator,
    z: Locator,
    intensity: Option<Locator>,
    ring: Option<Locator>,
    time: Option<Locator>,
}

impl Layout {
    fn new(header: &Header) -> Result<Layout, &'static str> {
        let find = |role| {
            let (mut offset, mut value_index) = (0, 0);
            for f in &header.fields {
                if f.role == role {
                    return Some(Slot { offset, bytes: f.bytes(), value_index, scalar: f.scalar });
                }
                offset += f.bytes();
                value_index += f.count;
            }
            None
        };
        Ok(Layout {
            stride: header.stride,
            x: find(Role::X).ok_or("x")?,
            y: find(Role::Y).ok_or("y")?,
            z: find(Role::Z).ok_or("z")?,
            intensity: find(Role::Intensity),
            ring: find(Role::Ring),
            time: find(Role::Time),
        })
    }

    fn locators(&self, at: impl Fn(&Slot) -> Locator) -> Locators {
        Locators {
            x: at(&self.x),
            y: at(&self.y),
            z: at(&self.z),
            intensity: self.intensity.as_ref().map(&at),
            ring: self.ring.as_ref().map(&at),
            time: self.time.as_ref().map(&at),
        }
    }

    /// Interleaved records (`binary`).
    fn aos(&self) -> Locators {
        let stride = self.stride();
        self.locators(|s| Locator { start: s.offset, step: stride, scalar: s.scalar })
    }

    /// One array per field (`binary_compressed`): field block starts at points × offset.
    fn soa(&self, header: &Header) -> Locators {
        let n = header.points;
        self.locators(|s| Locator { start: n * s.offset, step: s.bytes, scalar: s.scalar })
    }

    fn stride(&self) -> usize {
        self.stride
    }
}

/// Builds a point from its values, or `None` if it is to be skipped.
#[inline]
fn make_point(x: f64, y: f64, z: f64, intensity: f64, ring: f64, time: f64) -> Option<Point> {
    let (x, y, z) = (x as f32, y as f32, z as f32);
    let valid = x.is_finite() && y.is_finite() && z.is_finite() && (x, y, z) != (0.0, 0.0, 0.0);
    // Float-to-int `as` saturates (NaN → 0), which is what an odd ring value deserves.
    valid.then_some(Point { x, y, z, intensity: intensity as f32, ring: ring as u16, time })
}

/// Reads `points` records from a checked data block into `out` (empty on entry);
/// returns how many were skipped. Works column by column so each inner loop handles one
/// field of one type.
fn read_records(data: &[u8], points: usize, loc: &Locators, out: &mut Vec<Point>) -> usize {
    out.resize(points, Point::default());
    // Blocks that stay in L1 cache while each column passes over them.
    for (b, block) in out.chunks_mut(BLOCK).enumerate() {
        let first = b * BLOCK;
        fill(data, &loc.x, first, block, |p, v| p.x = v as f32);
        fill(data, &loc.y, first, block, |p, v| p.y = v as f32);
        fill(data, &loc.z, first, block, |p, v| p.z = v as f32);
        if let Some(l) = &loc.intensity {
            fill(data, l, first, block, |p, v| p.intensity = v as f32);
        }
        if let Some(l) = &loc.ring {
            // Float-to-int `as` saturates (NaN → 0), what an odd ring value deserves.
            fill(data, l, first, block, |p, v| p.ring = v as u16);
        }
        if let Some(l) = &loc.time {
            fill(data, l, first, block, |p, v| p.time = v);
        }
    }
    out.retain(is_valid);
    points - out.len()
}

/// Points per block of [`read_records`] (8 KiB of `Point`s).
const BLOCK: usize = 256;

/// Whether a point is a real return: finite and not exactly at the origin.
fn is_valid(p: &Point) -> bool {
    p.x.is_finite() && p.y.is_finite() && p.z.is_finite() && (p.x, p.y, p.z) != (0.0, 0.0, 0.0)
}

/// Sets one field of the points `first..first + out.len()` from column `loc` of `data`.
fn fill(
    data: &[u8],
    loc: &Locator,
    first: usize,
    out: &mut [Point],
    set: impl Fn(&mut Point, f64),
) {
    let loc = &Locator { start: loc.start + first * loc.step, ..*loc };
    match loc.scalar {
        Scalar::F4 => column(data, loc, out, |b| f64::from(f32::from_le_bytes(b)), set),
        Scalar::F8 => column(data, loc, out, f64::from_le_bytes, set),
        Scalar::I1 => column(data, loc, out, |b| f64::from(i8::from_le_bytes(b)), set),
        Scalar::I2 => column(data, loc, out, |b| f64::from(i16::from_le_bytes(b)), set),
        Scalar::I4 => column(data, loc, out, |b| f64::from(i32::from_le_bytes(b)), set),
        Scalar::I8 => column(data, loc, out, |b| i64::from_le_bytes(b) as f64, set),
        Scalar::U1 => column(data, loc, out, |b: [u8; 1]| f64::from(b[0]), set),
        Scalar::U2 => column(data, loc, out, |b| f64::from(u16::from_le_bytes(b)), set),
        Scalar::U4 => column(data, loc, out, |b| f64::from(u32::from_le_bytes(b)), set),
        Scalar::U8 => column(data, loc, out, |b| u64::from_le_bytes(b) as f64, set),
    }
}

/// The inner loop of [`fill`] for a scalar of `N` bytes; NaN where `data` is too short
/// (cannot happen after [`sized`], but costs nothing and cannot panic).
#[inline(always)]
fn column<const N: usize>(
    data: &[u8],
    loc: &Locator,
    out: &mut [Point],
    convert: impl Fn([u8; N]) -> f64,
    set: impl Fn(&mut Point, f64),
) {
    for (i, p) in out.iter_mut().enumerate() {
        let at = loc.start + i * loc.step;
        let bytes = data.get(at..at + N).and_then(|b| <[u8; N]>::try_from(b).ok());
        set(p, bytes.map_or(f64::NAN, &convert));
    }
}

/// The first `points × stride` bytes of `data`, or a truncation error.
fn sized<'d>(
    data: &'d [u8],
    points: usize,
    stride: usize,
    what: &'static str,
    name: &Name<'_>,
) -> Result<&'d [u8], PcdError> {
    let needed = (points as u64).saturating_mul(stride as u64);
    if (data.len() as u64) < needed {
        return Err(PcdError::Truncated {
            file: name.to_string(),
            what,
            needed,
            available: data.len() as u64,
        });
    }
    Ok(&data[..needed as usize])
}

/// Decompresses a `binary_compressed` data section into `scratch`.
fn decompress<'s>(
    data: &[u8],
    header: &Header,
    name: &Name<'_>,
    scratch: &'s mut Vec<u8>,
) -> Result<&'s [u8], PcdError> {
    let sizes = sized(data, 1, 8, "compressed size fields", name)?;
    let compressed_len = u32::from_le_bytes([sizes[0], sizes[1], sizes[2], sizes[3]]) as usize;
    let raw_len = u32::from_le_bytes([sizes[4], sizes[5], sizes[6], sizes[7]]) as u64;
    let compressed = sized(&data[8..], 1, compressed_len, "compressed data", name)?;
    let needed = (header.points as u64).saturating_mul(header.stride as u64);
    let err = |problem: String| PcdError::Compressed { file: name.to_string(), problem };
    if raw_len != needed {
        return Err(err(format!(
            "uncompressed size {raw_len} is not POINTS × record size = {needed}"
        )));
    }
    // The compressed bytes are present (checked above), so this bounds the allocation
    // below by the file's size.
    if raw_len > lzf::max_decompressed_len(compressed_len) as u64 {
        return Err(err(format!(
            "uncompressed size {raw_len} is impossible for {compressed_len} compressed bytes \
             (LZF expands at most {}×)",
            lzf::MAX_EXPANSION
        )));
    }
    scratch.clear();
    scratch.resize(raw_len as usize, 0);
    let n = lzf::decompress(compressed, scratch).map_err(|e| err(e.to_string()))?;
    if (n as u64) < needed {
        return Err(err(format!("decompressed to {n} bytes, {needed} expected")));
    }
    Ok(&scratch[..n])
}

/// Reads the ascii data section; returns how many points were skipped.
fn read_ascii(
    data: &[u8],
    header: &Header,
    layout: &Layout,
    name: &Name<'_>,
    out: &mut Vec<Point>,
) -> Result<usize, PcdError> {
    let values: usize = header.fields.iter().map(|f| f.count).sum();
    // A point line has at least one byte per value, so this bounds the reservation.
    out.reserve(header.points.min(data.len() / values.max(1) / 2 + 1));
    let mut read = 0;
    let mut skipped = 0;
    let mut line_no = 0;
    let mut rest = data;
    while read < header.points && !rest.is_empty() {
        line_no += 1;
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        let line = &rest[..end];
        rest = rest.get(end + 1..).unwrap_or(&[]);
        let err =
            |problem: String| PcdError::Ascii { file: name.to_string(), line: line_no, problem };
        let text = core::str::from_utf8(line).map_err(|_| err("not text".into()))?.trim();
        if text.is_empty() {
            continue;
        }
        let mut v = [0.0f64; 6];
        let wanted = [
            Some(layout.x),
            Some(layout.y),
            Some(layout.z),
            layout.intensity,
            layout.ring,
            layout.time,
        ];
        let mut found = 0;
        for (k, word) in text.split_ascii_whitespace().enumerate() {
            found = k + 1;
            for (slot, value) in wanted.iter().zip(v.iter_mut()) {
                if let Some(s) = slot.filter(|s| s.value_index == k) {
                    *value = parse_value(word, s.scalar)
                        .ok_or_else(|| err(format!("`{}` is not a number", truncate(word))))?;
                }
            }
        }
        if found < values {
            return Err(err(format!("{found} values, the header declares {values}")));
        }
        read += 1;
        match make_point(v[0], v[1], v[2], v[3], v[4], v[5]) {
            Some(p) => out.push(p),
            None => skipped += 1,
        }
    }
    if read < header.points {
        return Err(PcdError::Truncated {
            file: name.to_string(),
            what: "ascii data (one line per point)",
            needed: header.points as u64,
            available: read as u64,
        });
    }
    Ok(skipped)
}

/// Parses an ascii value of a field of type `scalar`; `nan`, `inf` in any case are
/// numbers too. F4 values are parsed as `f32` directly: going through `f64` could round
/// twice and miss the written value by one ulp.
fn parse_value(word: &str, scalar: Scalar) -> Option<f64> {
    match scalar {
        Scalar::F4 => word.parse::<f32>().ok().map(f64::from),
        _ => word.parse::<f64>().ok(),
    }
}

// ---------------------------------------------------------------------------------------
// Writer

fn encode_ascii(points: &[Point], out: &mut Vec<u8>) {
    for p in points {
        // `{}` prints the shortest string that reads back to the same f32.
        let _ = writeln!(out, "{} {} {} {} {}", p.x, p.y, p.z, p.intensity, p.ring);
    }
}

fn encode_binary(points: &[Point], out: &mut Vec<u8>) {
    out.reserve(points.len() * 18);
    for p in points {
        for v in [p.x, p.y, p.z, p.intensity] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&p.ring.to_le_bytes());
    }
}

fn encode_compressed(points: &[Point], out: &mut Vec<u8>) {
    let mut raw = Vec::with_capacity(points.len() * 18);
    for get in [|p: &Point| p.x, |p: &Point| p.y, |p: &Point| p.z, |p: &Point| p.intensity] {
        for p in points {
            raw.extend_from_slice(&get(p).to_le_bytes());
        }
    }
    for p in points {
        raw.extend_from_slice(&p.ring.to_le_bytes());
    }
    let mut packed = vec![0u8; lzf::max_compressed_len(raw.len())];
    // The buffer has the worst-case size, so compression cannot run out of room.
    let n = lzf::compress(&raw, &mut packed).unwrap_or(0);
    out.extend_from_slice(&(n as u32).to_le_bytes());
    out.extend_from_slice(&(raw.len() as u32).to_le_bytes());
    out.extend_from_slice(&packed[..n]);
}
