//! PLY point clouds: ascii, binary little and big endian; x/y/z of any numeric type; optional
//! normals (`nx ny nz`), colours (`red green blue`, or `diffuse_*`, or `r g b`) and intensity;
//! other elements (faces, cameras) are read past and ignored. Points with a non-finite
//! coordinate are skipped and counted. Writing is binary little-endian with double coordinates
//! (TLS coordinates are large).
//!
//! The reader is our own (header in [`header`], body here); ply-rs was dropped because its
//! header grammar panicked on hostile integers and merged duplicated properties (see
//! [`header`]). What it refuses, with the file and the line (header, ascii body) or byte offset
//! (binary body): a header the file's length cannot satisfy (the declared counts are checked
//! against the bytes that follow before anything is allocated or looped), an element that
//! declares instances but no property, extra values on an ascii row, bytes after the last
//! element, list lengths that are negative or run past the end.

pub mod header;

use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use nalgebra::{Point3, Vector3};

use self::header::{Element, Format, Header, Kind, Scalar, read_header};
use super::atomic::StagedFile;
use super::error::{ReadError, ReadErrorKind, WriteError, open_file};

/// A point cloud with optional per-point attributes (each `Some` vector has one entry per point).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Point positions.
    pub points: Vec<Point3<f64>>,
    /// Unit normals, if the file has them.
    pub normals: Option<Vec<Vector3<f64>>>,
    /// RGB colours, if the file has them.
    pub colors: Option<Vec<[u8; 3]>>,
    /// Intensities, if the file has them.
    pub intensity: Option<Vec<f32>>,
}

impl PointCloud {
    /// A cloud of bare points.
    #[must_use]
    pub fn from_points(points: Vec<Point3<f64>>) -> Self {
        PointCloud {
            points,
            ..Default::default()
        }
    }

    /// Number of points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// The result of reading a PLY file.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyRead {
    /// The finite points and their attributes.
    pub cloud: PointCloud,
    /// Vertices declared (and read) in the file.
    pub vertices_in_file: usize,
    /// Vertices dropped because a coordinate was NaN or infinite.
    pub skipped_non_finite: usize,
}

/// Names a colour channel may have, per channel.
const COLOUR_NAMES: [[&str; 3]; 3] = [
    ["red", "diffuse_red", "r"],
    ["green", "diffuse_green", "g"],
    ["blue", "diffuse_blue", "b"],
];
/// Names intensity may have.
const INTENSITY_NAMES: [&str; 3] = ["intensity", "scalar_intensity", "scalar_Intensity"];

/// Where the vertex element keeps what we read: property positions.
#[derive(Clone, Debug)]
struct VertexLayout {
    xyz: [usize; 3],
    normals: Option<[usize; 3]>,
    colors: Option<[(usize, Scalar); 3]>,
    intensity: Option<usize>,
}

/// The scalar type of a property, or an error when it is a list.
fn scalar_of(path: &Path, element: &Element, k: usize) -> Result<Scalar, ReadError> {
    let p = &element.properties[k];
    match p.kind {
        Kind::Scalar(t) => Ok(t),
        Kind::List { .. } => Err(ReadError::at_line(
            path,
            element.line,
            ReadErrorKind::Invalid(format!(
                "vertex property `{}` is a list, expected a number",
                p.name
            )),
        )),
    }
}

fn vertex_layout(path: &Path, vertex: &Element) -> Result<VertexLayout, ReadError> {
    let mut xyz = [0; 3];
    for (slot, name) in xyz.iter_mut().zip(["x", "y", "z"]) {
        *slot = vertex
            .position(name)
            .ok_or_else(|| ReadError::new(path, ReadErrorKind::MissingProperty(name)))?;
        scalar_of(path, vertex, *slot)?;
    }
    let find = |names: &[&str]| names.iter().find_map(|n| vertex.position(n));
    let normals = match (find(&["nx"]), find(&["ny"]), find(&["nz"])) {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    if let Some(n) = normals {
        for k in n {
            scalar_of(path, vertex, k)?;
        }
    }
    let colors = match COLOUR_NAMES.map(|names| find(&names)) {
        [Some(r), Some(g), Some(b)] => Some([
            (r, scalar_of(path, vertex, r)?),
            (g, scalar_of(path, vertex, g)?),
            (b, scalar_of(path, vertex, b)?),
        ]),
        _ => None,
    };
    let intensity = find(&INTENSITY_NAMES);
    if let Some(k) = intensity {
        scalar_of(path, vertex, k)?;
    }
    Ok(VertexLayout {
        xyz,
        normals,
        colors,
        intensity,
    })
}

/// An 8-bit colour channel from a value of any type: 16-bit values keep their high byte,
/// floating-point values in [0, 1] are scaled to 255.
fn colour_from(value: f64, t: Scalar) -> u8 {
    let v = match t {
        Scalar::U16 => value / 256.0,
        Scalar::F32 | Scalar::F64 => value * 255.0,
        _ => value,
    };
    if v.is_nan() {
        0
    } else {
        v.round().clamp(0.0, 255.0) as u8
    }
}

/// Where a streamed read hands its points: `(chunk length, consumer)`.
type Sink<'a> = (usize, &'a mut dyn FnMut(&[Point3<f64>]));

/// The cloud being filled, one vertex at a time; with a sink, handed on in chunks instead of
/// kept.
struct CloudBuilder<'a> {
    layout: VertexLayout,
    cloud: PointCloud,
    skipped: usize,
    sink: Option<Sink<'a>>,
}

impl<'a> CloudBuilder<'a> {
    fn new(layout: VertexLayout, capacity: usize, sink: Option<Sink<'a>>) -> Self {
        let capacity = sink.as_ref().map_or(capacity, |(n, _)| capacity.min(*n));
        let cloud = PointCloud {
            points: Vec::with_capacity(capacity),
            normals: layout.normals.map(|_| Vec::with_capacity(capacity)),
            colors: layout.colors.map(|_| Vec::with_capacity(capacity)),
            intensity: layout.intensity.map(|_| Vec::with_capacity(capacity)),
        };
        CloudBuilder {
            layout,
            cloud,
            skipped: 0,
            sink,
        }
    }

    /// Hands the points gathered so far to the sink (if any) and forgets them.
    fn flush(&mut self) {
        if let Some((_, f)) = self.sink.as_mut() {
            if !self.cloud.points.is_empty() {
                f(&self.cloud.points);
            }
            self.cloud.points.clear();
        }
    }

    /// Adds a vertex from its property values (lists hold NaN).
    fn push(&mut self, values: &[f64]) {
        let l = &self.layout;
        let [x, y, z] = l.xyz.map(|k| values[k]);
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            self.skipped += 1;
            return;
        }
        self.cloud.points.push(Point3::new(x, y, z));
        if let Some((n, _)) = self.sink.as_ref() {
            if self.cloud.points.len() >= *n {
                self.flush();
            }
            return;
        }
        if let (Some(n), Some(idx)) = (self.cloud.normals.as_mut(), l.normals) {
            n.push(Vector3::from(idx.map(|k| values[k])));
        }
        if let (Some(c), Some(idx)) = (self.cloud.colors.as_mut(), l.colors) {
            c.push(idx.map(|(k, t)| colour_from(values[k], t)));
        }
        if let (Some(i), Some(k)) = (self.cloud.intensity.as_mut(), l.intensity) {
            i.push(values[k] as f32);
        }
    }
}

/// Reads a PLY point cloud.
///
/// # Errors
///
/// [`ReadError`] naming the file and the line (header, ascii body) or byte (binary body): not
/// found, a directory, not a PLY file, an inconsistent header ([`header::read_header`]), no
/// `vertex` element or no x/y/z, counts the file's length cannot hold, a value that does not
/// parse, extra values on an ascii row, bytes after the last element.
pub fn read(path: &Path) -> Result<PlyRead, ReadError> {
    read_file(path, Attributes::All)
}

/// Reads only the coordinates of a PLY point cloud (normals, colours and intensity are read
/// past, not kept): what measuring needs, in 24 bytes per point.
///
/// # Errors
///
/// As [`read`].
pub fn read_points(path: &Path) -> Result<PlyRead, ReadError> {
    read_file(path, Attributes::None)
}

/// Reads a PLY point cloud held in memory; `path` only names it in errors.
///
/// # Errors
///
/// As [`read`].
pub fn parse(path: &Path, bytes: &[u8]) -> Result<PlyRead, ReadError> {
    read_from(path, bytes, bytes.len() as u64, Attributes::All, None)
}

/// What a streamed read saw: every vertex of the file, and those left out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamSummary {
    /// Vertices (points) in the file.
    pub vertices_in_file: usize,
    /// Vertices left out because a coordinate was NaN or infinite (or, in E57, invalid).
    pub skipped_non_finite: usize,
}

impl StreamSummary {
    /// What a whole read saw.
    fn of(read: &PlyRead) -> Self {
        StreamSummary {
            vertices_in_file: read.vertices_in_file,
            skipped_non_finite: read.skipped_non_finite,
        }
    }

    /// An error naming `path` when the file held no finite point.
    ///
    /// # Errors
    ///
    /// [`ReadError`] `no finite points (N vertices, M not finite)`.
    pub fn require_finite(&self, path: &Path) -> Result<(), ReadError> {
        if self.vertices_in_file > self.skipped_non_finite {
            return Ok(());
        }
        Err(ReadError::new(
            path,
            ReadErrorKind::Invalid(format!(
                "no finite points ({} vertices, {} not finite)",
                self.vertices_in_file, self.skipped_non_finite
            )),
        ))
    }
}

/// The number of vertices a PLY file's header declares (the body is not read: a caller's
/// estimate, checked when the body is read).
///
/// # Errors
///
/// As [`read`], for the header.
pub fn vertex_count(path: &Path) -> Result<u64, ReadError> {
    let mut reader = BufReader::new(open_file(path)?);
    let header = read_header(path, &mut reader)?;
    Ok(header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map_or(0, |e| e.count))
}

/// [`stream_points`] on a PLY file held in memory; `path` only names it in errors.
///
/// # Errors
///
/// As [`read`].
pub fn parse_streamed(
    path: &Path,
    bytes: &[u8],
    chunk: usize,
    f: &mut dyn FnMut(&[Point3<f64>]),
) -> Result<StreamSummary, ReadError> {
    streamed(path, bytes, bytes.len() as u64, chunk, f)
}

/// Reads the coordinates of a PLY point cloud in chunks of at most `chunk` finite points,
/// each handed to `f` in file order and then forgotten: a scan of any size in bounded memory.
/// The header and the declared counts are checked against the file's length first, as by
/// [`read`]; an error in the body comes after some chunks were handed on, so the caller must
/// discard what it built from them.
///
/// # Errors
///
/// As [`read`].
pub fn stream_points(
    path: &Path,
    chunk: usize,
    f: &mut dyn FnMut(&[Point3<f64>]),
) -> Result<StreamSummary, ReadError> {
    let (reader, len) = open_sized(path)?;
    streamed(path, reader, len, chunk, f)
}

/// The coordinates of a PLY cloud of `len` bytes from `reader`, handed to `f` in chunks.
fn streamed<R: BufRead>(
    path: &Path,
    reader: R,
    len: u64,
    chunk: usize,
    f: &mut dyn FnMut(&[Point3<f64>]),
) -> Result<StreamSummary, ReadError> {
    let read = read_from(path, reader, len, Attributes::None, Some((chunk.max(1), f)))?;
    Ok(StreamSummary::of(&read))
}

/// Which per-point attributes to keep.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Attributes {
    /// Normals, colours and intensity when the file has them.
    All,
    /// Coordinates only.
    None,
}

fn read_file(path: &Path, attributes: Attributes) -> Result<PlyRead, ReadError> {
    let (reader, len) = open_sized(path)?;
    read_from(path, reader, len, attributes, None)
}

/// The file `path` opened for reading with a 1 MB buffer, and its length in bytes.
fn open_sized(path: &Path) -> Result<(BufReader<std::fs::File>, u64), ReadError> {
    let file = open_file(path)?;
    let len = file
        .metadata()
        .map_err(|e| ReadError::new(path, ReadErrorKind::Io(e)))?
        .len();
    Ok((BufReader::with_capacity(1 << 20, file), len))
}

/// Reads a PLY cloud of `len` bytes from `reader`.
fn read_from<R: BufRead>(
    path: &Path,
    mut reader: R,
    len: u64,
    attributes: Attributes,
    sink: Option<Sink<'_>>,
) -> Result<PlyRead, ReadError> {
    let header = read_header(path, &mut reader)?;
    let Some(vertex) = header.elements.iter().find(|e| e.name == "vertex") else {
        return Err(ReadError::new(
            path,
            ReadErrorKind::Invalid("no `vertex` element".into()),
        ));
    };
    let mut layout = vertex_layout(path, vertex)?;
    if attributes == Attributes::None {
        (layout.normals, layout.colors, layout.intensity) = (None, None, None);
    }
    check_counts(path, &header, len)?;
    // Every vertex takes at least `min_bytes` of the body, so this never exceeds what the file
    // holds (checked just above).
    let capacity = usize::try_from(vertex.count).unwrap_or(usize::MAX);
    let mut builder = CloudBuilder::new(layout, capacity, sink);
    let mut body = Body {
        reader,
        pos: header.bytes,
        line: header.lines,
    };
    for element in &header.elements {
        let is_vertex = element.name == "vertex";
        match header.format {
            Format::Ascii => {
                body.ascii_element(path, element, is_vertex.then_some(&mut builder))?
            }
            f => body.binary_element(
                path,
                element,
                f == Format::BinaryBigEndian,
                is_vertex.then_some(&mut builder),
            )?,
        }
    }
    body.expect_end(path, header.format)?;
    builder.flush();
    Ok(PlyRead {
        cloud: builder.cloud,
        vertices_in_file: capacity,
        skipped_non_finite: builder.skipped,
    })
}

/// Checks the declared counts against the bytes after the header, before anything is
/// allocated or looped: an element that declares instances but no property, or more instances
/// than the rest of the file can hold even at their smallest, is an error.
fn check_counts(path: &Path, header: &Header, len: u64) -> Result<(), ReadError> {
    let available = len.saturating_sub(header.bytes);
    let mut needed = 0u128;
    for e in &header.elements {
        if e.properties.is_empty() && e.count > 0 {
            return Err(ReadError::at_line(
                path,
                e.line,
                ReadErrorKind::Invalid(format!(
                    "element `{}` declares {} instances but no property",
                    e.name, e.count
                )),
            ));
        }
        let min = e.min_bytes(header.format);
        needed += u128::from(e.count) * u128::from(min);
        if needed > u128::from(available) {
            let fit = (u128::from(available) - (needed - u128::from(e.count) * u128::from(min)))
                / u128::from(min.max(1));
            return Err(ReadError::at_line(
                path,
                e.line,
                ReadErrorKind::Truncated(format!(
                    "ends after {fit} of {} `{}` elements: they need at least {min} bytes each and \
                     the {available} bytes after the header cannot hold them",
                    e.count, e.name
                )),
            ));
        }
    }
    Ok(())
}

/// The body being read: position in bytes (binary errors) and in lines (ascii errors).
struct Body<R> {
    reader: R,
    pos: u64,
    line: usize,
}

/// Decodes one binary scalar.
fn decode(bytes: &[u8], t: Scalar, big: bool) -> f64 {
    macro_rules! num {
        ($ty:ty, $n:expr) => {{
            let mut a = [0u8; $n];
            a.copy_from_slice(&bytes[..$n]);
            f64::from(if big {
                <$ty>::from_be_bytes(a)
            } else {
                <$ty>::from_le_bytes(a)
            })
        }};
    }
    match t {
        Scalar::I8 => f64::from(bytes[0] as i8),
        Scalar::U8 => f64::from(bytes[0]),
        Scalar::I16 => num!(i16, 2),
        Scalar::U16 => num!(u16, 2),
        Scalar::I32 => num!(i32, 4),
        Scalar::U32 => num!(u32, 4),
        Scalar::F32 => num!(f32, 4),
        Scalar::F64 => num!(f64, 8),
    }
}

impl<R: BufRead> Body<R> {
    /// Reads exactly `buf.len()` bytes.
    fn fill(&mut self, buf: &mut [u8]) -> std::io::Result<()> {
        self.reader.read_exact(buf)?;
        self.pos += buf.len() as u64;
        Ok(())
    }

    /// A binary element error at the current byte.
    fn byte_error(&self, path: &Path, kind: ReadErrorKind) -> ReadError {
        ReadError::at_byte(path, self.pos, kind)
    }

    /// Maps an I/O error inside element `k` of `e`.
    fn io_error(&self, path: &Path, e: std::io::Error, k: u64, element: &Element) -> ReadError {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            self.byte_error(
                path,
                ReadErrorKind::Truncated(format!(
                    "ends after {k} of {} `{}` elements",
                    element.count, element.name
                )),
            )
        } else {
            self.byte_error(path, ReadErrorKind::Io(e))
        }
    }

    /// Reads (vertex) or reads past (any other element) every instance of a binary element.
    fn binary_element(
        &mut self,
        path: &Path,
        element: &Element,
        big: bool,
        mut vertex: Option<&mut CloudBuilder<'_>>,
    ) -> Result<(), ReadError> {
        let mut values = vec![f64::NAN; element.properties.len()];
        if let Some(size) = element.fixed_size() {
            // Fixed-size records: read in blocks, decode the vertex's values by offset.
            let offsets: Vec<(usize, Scalar)> = element
                .properties
                .iter()
                .scan(0, |at, p| {
                    let Kind::Scalar(t) = p.kind else {
                        return None;
                    };
                    let here = *at;
                    *at += t.size();
                    Some((here, t))
                })
                .collect();
            let per_block = ((1usize << 16) / size.max(1)).max(1);
            let mut block = vec![0u8; per_block * size];
            let mut k = 0u64;
            while k < element.count {
                let n = (element.count - k).min(per_block as u64) as usize;
                let buf = &mut block[..n * size];
                if let Err(e) = self.fill(buf) {
                    return Err(self.io_error(path, e, k, element));
                }
                if let Some(v) = vertex.as_deref_mut() {
                    for record in buf.chunks_exact(size) {
                        for (value, &(at, t)) in values.iter_mut().zip(&offsets) {
                            *value = decode(&record[at..], t, big);
                        }
                        v.push(&values);
                    }
                }
                k += n as u64;
            }
            return Ok(());
        }
        let mut scratch = [0u8; 8];
        for k in 0..element.count {
            let start = self.pos;
            for (value, p) in values.iter_mut().zip(&element.properties) {
                match p.kind {
                    Kind::Scalar(t) => {
                        let b = &mut scratch[..t.size()];
                        if let Err(e) = self.fill(b) {
                            return Err(self.io_error(path, e, k, element));
                        }
                        *value = decode(b, t, big);
                    }
                    Kind::List { count, item } => {
                        let at = self.pos;
                        let b = &mut scratch[..count.size()];
                        if let Err(e) = self.fill(b) {
                            return Err(self.io_error(path, e, k, element));
                        }
                        let n = decode(b, count, big);
                        if n < 0.0 {
                            return Err(ReadError::at_byte(
                                path,
                                at,
                                ReadErrorKind::Invalid(format!(
                                    "`{}` element {k} (from byte {start}): list `{}` has length {n}",
                                    element.name, p.name
                                )),
                            ));
                        }
                        let bytes = n as u64 * item.size() as u64;
                        if let Err(e) = self.skip(bytes) {
                            return Err(self.io_error(path, e, k, element));
                        }
                        *value = f64::NAN;
                    }
                }
            }
            if let Some(v) = vertex.as_deref_mut() {
                v.push(&values);
            }
        }
        Ok(())
    }

    /// Reads past `n` bytes.
    fn skip(&mut self, mut n: u64) -> std::io::Result<()> {
        while n > 0 {
            let available = self.reader.fill_buf()?.len();
            if available == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            let step = available.min(usize::try_from(n).unwrap_or(usize::MAX));
            self.reader.consume(step);
            self.pos += step as u64;
            n -= step as u64;
        }
        Ok(())
    }

    /// Reads one line (without its line break); `None` at the end of the file.
    fn next_line(&mut self, path: &Path, buf: &mut Vec<u8>) -> Result<Option<()>, ReadError> {
        buf.clear();
        let n = self
            .reader
            .read_until(b'\n', buf)
            .map_err(|e| ReadError::at_line(path, self.line + 1, ReadErrorKind::Io(e)))?;
        if n == 0 {
            return Ok(None);
        }
        self.pos += n as u64;
        self.line += 1;
        Ok(Some(()))
    }

    /// Reads (vertex) or reads past every line of an ascii element.
    fn ascii_element(
        &mut self,
        path: &Path,
        element: &Element,
        mut vertex: Option<&mut CloudBuilder<'_>>,
    ) -> Result<(), ReadError> {
        let mut values = vec![f64::NAN; element.properties.len()];
        let mut line = Vec::new();
        for k in 0..element.count {
            if self.next_line(path, &mut line)?.is_none() {
                return Err(ReadError::at_line(
                    path,
                    self.line,
                    ReadErrorKind::Truncated(format!(
                        "ends after {k} of {} `{}` elements",
                        element.count, element.name
                    )),
                ));
            }
            parse_ascii_row(&line, element, &mut values)
                .map_err(|kind| ReadError::at_line(path, self.line, kind))?;
            if let Some(v) = vertex.as_deref_mut() {
                v.push(&values);
            }
        }
        Ok(())
    }

    /// After the last element: nothing but blank space in ascii, nothing at all in binary.
    fn expect_end(&mut self, path: &Path, format: Format) -> Result<(), ReadError> {
        if format == Format::Ascii {
            let mut line = Vec::new();
            while self.next_line(path, &mut line)?.is_some() {
                if !line.trim_ascii().is_empty() {
                    return Err(ReadError::at_line(
                        path,
                        self.line,
                        ReadErrorKind::Invalid(
                            "text after the last element the header declares".into(),
                        ),
                    ));
                }
            }
            return Ok(());
        }
        let start = self.pos;
        let mut extra = 0u64;
        loop {
            let pos = self.pos + extra;
            let n = self
                .reader
                .fill_buf()
                .map_err(|e| ReadError::at_byte(path, pos, ReadErrorKind::Io(e)))?
                .len();
            if n == 0 {
                break;
            }
            self.reader.consume(n);
            extra += n as u64;
        }
        if extra > 0 {
            return Err(ReadError::at_byte(
                path,
                start,
                ReadErrorKind::Invalid(format!(
                    "{extra} bytes after the last element the header declares"
                )),
            ));
        }
        Ok(())
    }
}

/// Parses one ascii row into `values` (lists hold NaN). Tokens are parsed with Rust's number
/// parsers, which take `nan`, `inf`, `.5` and `1E3` as real scanners write them; integers must
/// fit their declared type.
fn parse_ascii_row(
    line: &[u8],
    element: &Element,
    values: &mut [f64],
) -> Result<(), ReadErrorKind> {
    let mut tokens = line
        .split(u8::is_ascii_whitespace)
        .filter(|t| !t.is_empty());
    for (value, p) in values.iter_mut().zip(&element.properties) {
        let mut next = |what: &str| {
            tokens.next().ok_or_else(|| {
                ReadErrorKind::Truncated(format!("the line ends before {what} `{}`", p.name))
            })
        };
        match p.kind {
            Kind::Scalar(t) => *value = parse_token(next("property")?, t, &p.name)?,
            Kind::List { count, item } => {
                let n = parse_token(next("the length of list")?, count, &p.name)?;
                if n < 0.0 {
                    return Err(ReadErrorKind::Invalid(format!(
                        "list `{}` has length {n}",
                        p.name
                    )));
                }
                for _ in 0..n as u64 {
                    parse_token(next("an item of list")?, item, &p.name)?;
                }
                *value = f64::NAN;
            }
        }
    }
    let extra = tokens.count();
    if extra > 0 {
        return Err(ReadErrorKind::Invalid(format!(
            "{extra} values after the last property `{}` of element `{}`",
            element.properties.last().map_or("", |p| p.name.as_str()),
            element.name
        )));
    }
    Ok(())
}

/// One ascii value of type `t`.
fn parse_token(token: &[u8], t: Scalar, name: &str) -> Result<f64, ReadErrorKind> {
    let text = std::str::from_utf8(token).unwrap_or("");
    let bad = || {
        ReadErrorKind::Invalid(format!(
            "value {:?} of `{name}` is not a valid {}",
            String::from_utf8_lossy(&token[..token.len().min(40)]),
            t.name()
        ))
    };
    let v = match t {
        Scalar::I8 => text.parse::<i8>().map(f64::from).ok(),
        Scalar::U8 => text.parse::<u8>().map(f64::from).ok(),
        Scalar::I16 => text.parse::<i16>().map(f64::from).ok(),
        Scalar::U16 => text.parse::<u16>().map(f64::from).ok(),
        Scalar::I32 => text.parse::<i32>().map(f64::from).ok(),
        Scalar::U32 => text.parse::<u32>().map(f64::from).ok(),
        Scalar::F32 => text.parse::<f32>().map(f64::from).ok(),
        Scalar::F64 => text.parse::<f64>().ok(),
    };
    v.ok_or_else(bad)
}

/// Writes a cloud as binary little-endian PLY (x, y, z as double; nx, ny, nz float; red, green,
/// blue uchar; intensity float), atomically.
///
/// # Errors
///
/// [`WriteError`] naming the file; also when an attribute vector's length differs from the
/// number of points.
pub fn write_binary(path: &Path, cloud: &PointCloud) -> Result<(), WriteError> {
    stage_binary(path, cloud)?.commit()
}

/// Writes a cloud as [`write_binary`] does, beside `path`, to be moved into place with the
/// other outputs of a command ([`StagedFile::commit`]).
///
/// # Errors
///
/// As [`write_binary`].
pub fn stage_binary(path: &Path, cloud: &PointCloud) -> Result<StagedFile, WriteError> {
    let n = cloud.points.len();
    let lengths_ok = cloud.normals.as_ref().is_none_or(|v| v.len() == n)
        && cloud.colors.as_ref().is_none_or(|v| v.len() == n)
        && cloud.intensity.as_ref().is_none_or(|v| v.len() == n);
    if !lengths_ok {
        return Err(WriteError::new(
            path,
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "attribute count differs from point count",
            ),
        ));
    }
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by pipemeasure\nelement vertex {n}\n"
    );
    let mut declare = |names: &[&str], t: Scalar| {
        for name in names {
            header.push_str(&format!("property {} {name}\n", t.name()));
        }
    };
    declare(&["x", "y", "z"], Scalar::F64);
    if cloud.normals.is_some() {
        declare(&["nx", "ny", "nz"], Scalar::F32);
    }
    if cloud.colors.is_some() {
        declare(&["red", "green", "blue"], Scalar::U8);
    }
    if cloud.intensity.is_some() {
        declare(&["intensity"], Scalar::F32);
    }
    header.push_str("end_header\n");
    StagedFile::write(path, |w| {
        w.write_all(header.as_bytes())?;
        for (k, p) in cloud.points.iter().enumerate() {
            for v in [p.x, p.y, p.z] {
                w.write_all(&v.to_le_bytes())?;
            }
            if let Some(normals) = &cloud.normals {
                for v in normals[k].iter() {
                    w.write_all(&(*v as f32).to_le_bytes())?;
                }
            }
            if let Some(colors) = &cloud.colors {
                w.write_all(&colors[k])?;
            }
            if let Some(intensity) = &cloud.intensity {
                w.write_all(&intensity[k].to_le_bytes())?;
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests;
