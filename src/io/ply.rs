//! PLY point clouds via `ply-rs`: ascii, binary little and big endian; x/y/z of any numeric
//! type; optional normals (`nx ny nz`), colours (`red green blue`, or `diffuse_*`) and intensity;
//! other elements (faces, cameras) are read past and ignored. Points with a non-finite
//! coordinate are skipped and counted. Writing is binary little-endian with double coordinates
//! (TLS coordinates are large).

use std::fs::File;
use std::io::{BufRead, BufReader, ErrorKind};
use std::path::Path;

use nalgebra::{Point3, Vector3};
use ply_rs::parser::Parser;
use ply_rs::ply::{
    Addable, DefaultElement, ElementDef, Encoding, Header, Property, PropertyAccess, PropertyDef,
    PropertyType, ScalarType,
};
use ply_rs::writer::Writer;

use super::atomic::write_atomic;
use super::error::{ReadError, ReadErrorKind, WriteError, open_error};

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

/// One vertex as read: every property we understand, converted to f64.
#[derive(Default)]
struct RawVertex {
    xyz: [f64; 3],
    normal: [f64; 3],
    rgb: [u8; 3],
    intensity: f32,
}

fn as_f64(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => f64::from(v),
        Property::UChar(v) => f64::from(v),
        Property::Short(v) => f64::from(v),
        Property::UShort(v) => f64::from(v),
        Property::Int(v) => f64::from(v),
        Property::UInt(v) => f64::from(v),
        Property::Float(v) => f64::from(v),
        Property::Double(v) => v,
        _ => return None,
    })
}

fn as_colour(p: &Property) -> u8 {
    match *p {
        Property::UChar(v) => v,
        Property::UShort(v) => (v >> 8) as u8,
        Property::Float(v) => (f64::from(v) * 255.0).round().clamp(0.0, 255.0) as u8,
        Property::Double(v) => (v * 255.0).round().clamp(0.0, 255.0) as u8,
        ref other => as_f64(other).unwrap_or(0.0).clamp(0.0, 255.0) as u8,
    }
}

impl PropertyAccess for RawVertex {
    fn new() -> Self {
        RawVertex::default()
    }

    fn set_property(&mut self, name: String, p: Property) {
        let v = || as_f64(&p).unwrap_or(f64::NAN);
        match name.as_str() {
            "x" => self.xyz[0] = v(),
            "y" => self.xyz[1] = v(),
            "z" => self.xyz[2] = v(),
            "nx" => self.normal[0] = v(),
            "ny" => self.normal[1] = v(),
            "nz" => self.normal[2] = v(),
            "red" | "diffuse_red" | "r" => self.rgb[0] = as_colour(&p),
            "green" | "diffuse_green" | "g" => self.rgb[1] = as_colour(&p),
            "blue" | "diffuse_blue" | "b" => self.rgb[2] = as_colour(&p),
            "intensity" | "scalar_intensity" | "scalar_Intensity" => self.intensity = v() as f32,
            _ => {}
        }
    }
}

/// Which optional attributes a vertex element carries.
struct Layout {
    normals: bool,
    colors: bool,
    intensity: bool,
}

fn layout(path: &Path, vertex: &ElementDef) -> Result<Layout, ReadError> {
    let has = |names: &[&str]| names.iter().any(|n| vertex.properties.contains_key(*n));
    for (axis, name) in [("x", "x"), ("y", "y"), ("z", "z")] {
        if !has(&[axis]) {
            return Err(ReadError::new(path, ReadErrorKind::MissingProperty(name)));
        }
        if let Some(def) = vertex.properties.get(axis)
            && matches!(def.data_type, PropertyType::List(..))
        {
            return Err(ReadError::new(
                path,
                ReadErrorKind::Invalid(format!(
                    "vertex property `{axis}` is a list, expected a number"
                )),
            ));
        }
    }
    Ok(Layout {
        normals: has(&["nx"]) && has(&["ny"]) && has(&["nz"]),
        colors: has(&["red", "diffuse_red", "r"]),
        intensity: has(&["intensity", "scalar_intensity", "scalar_Intensity"]),
    })
}

/// Reads a PLY point cloud.
///
/// # Errors
///
/// [`ReadError`] naming the file: not found, not a PLY file, no `vertex` element or no x/y/z,
/// or truncated (with how many vertices were read).
pub fn read(path: &Path) -> Result<PlyRead, ReadError> {
    let file = File::open(path).map_err(|e| open_error(path, e))?;
    let file_len = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut reader = BufReader::with_capacity(1 << 20, file);
    let header = read_header(path, &mut reader)?;
    let Some((_, vertex_def)) = header.elements.iter().find(|(k, _)| k.as_str() == "vertex") else {
        return Err(ReadError::new(
            path,
            ReadErrorKind::Invalid("no `vertex` element".into()),
        ));
    };
    let lay = layout(path, vertex_def)?;
    let vertex_parser = Parser::<RawVertex>::new();
    let skip_parser = Parser::<DefaultElement>::new();

    let declared = vertex_def.count;
    // Never trust a declared count for allocation beyond what the file can hold.
    let capacity = declared.min((file_len / 3) as usize);
    let mut cloud = PointCloud {
        points: Vec::with_capacity(capacity),
        normals: lay.normals.then(|| Vec::with_capacity(capacity)),
        colors: lay.colors.then(|| Vec::with_capacity(capacity)),
        intensity: lay.intensity.then(|| Vec::with_capacity(capacity)),
    };
    let mut skipped = 0;
    let mut line_no = header_lines(&header);
    for (name, def) in &header.elements {
        let is_vertex = name.as_str() == "vertex";
        for k in 0..def.count {
            line_no += 1;
            let fail = |e: ElementError| match e {
                ElementError::Eof => ReadError::new(
                    path,
                    ReadErrorKind::Truncated(format!(
                        "file ends after {k} of {} {name} elements",
                        def.count
                    )),
                ),
                ElementError::Io(e) => ReadError::at_line(path, line_no, ReadErrorKind::Io(e)),
                ElementError::Parse(m) => {
                    ReadError::at_line(path, line_no, ReadErrorKind::Invalid(m))
                }
            };
            if !is_vertex {
                read_element(&skip_parser, &mut reader, def, header.encoding).map_err(fail)?;
                continue;
            }
            let v =
                read_element(&vertex_parser, &mut reader, def, header.encoding).map_err(fail)?;
            if !v.xyz.iter().all(|c| c.is_finite()) {
                skipped += 1;
                continue;
            }
            cloud.points.push(Point3::new(v.xyz[0], v.xyz[1], v.xyz[2]));
            if let Some(n) = cloud.normals.as_mut() {
                n.push(Vector3::from(v.normal));
            }
            if let Some(c) = cloud.colors.as_mut() {
                c.push(v.rgb);
            }
            if let Some(i) = cloud.intensity.as_mut() {
                i.push(v.intensity);
            }
        }
    }
    Ok(PlyRead {
        cloud,
        vertices_in_file: declared,
        skipped_non_finite: skipped,
    })
}

/// Number of header lines (for ascii error positions): magic, format, comments, elements and
/// properties, end_header.
fn header_lines(h: &Header) -> usize {
    3 + h.comments.len()
        + h.obj_infos.len()
        + h.elements
            .values()
            .map(|e| 1 + e.properties.len())
            .sum::<usize>()
}

/// Why one element could not be read.
enum ElementError {
    /// The file ended.
    Eof,
    /// Another I/O failure.
    Io(std::io::Error),
    /// An ascii line did not parse.
    Parse(String),
}

/// Reads one element in the file's encoding.
fn read_element<E: PropertyAccess, R: BufRead>(
    parser: &Parser<E>,
    reader: &mut R,
    def: &ElementDef,
    encoding: Encoding,
) -> Result<E, ElementError> {
    let io = |e: std::io::Error| {
        if e.kind() == ErrorKind::UnexpectedEof {
            ElementError::Eof
        } else {
            ElementError::Io(e)
        }
    };
    match encoding {
        Encoding::BinaryLittleEndian => parser.read_little_endian_element(reader, def).map_err(io),
        Encoding::BinaryBigEndian => parser.read_big_endian_element(reader, def).map_err(io),
        Encoding::Ascii => {
            let mut line = String::new();
            if reader.read_line(&mut line).map_err(io)? == 0 {
                return Err(ElementError::Eof);
            }
            parse_ascii_element(&line, def).map_err(ElementError::Parse)
        }
    }
}

/// Parses one ascii element line. ply-rs's own ascii grammar rejects `nan`, `inf`, `.5` and
/// `1E3`, which real scanners write, so tokens are parsed here with Rust's number parsers.
fn parse_ascii_element<E: PropertyAccess>(line: &str, def: &ElementDef) -> Result<E, String> {
    let mut tokens = line.split_whitespace();
    let mut element = E::new();
    for (name, p) in &def.properties {
        let mut next = |what: &str| {
            tokens
                .next()
                .ok_or_else(|| format!("line ends before {what} `{name}`"))
        };
        let property = match &p.data_type {
            PropertyType::Scalar(t) => parse_scalar(next("property")?, t, name)?,
            PropertyType::List(_, t) => {
                let count_token = next("the length of list")?;
                let count: usize = count_token.parse().map_err(|_| {
                    format!("list length {count_token:?} of `{name}` is not a count")
                })?;
                let items: Vec<Property> = (0..count)
                    .map(|_| parse_scalar(next("an item of list")?, t, name))
                    .collect::<Result<_, _>>()?;
                list_property(t, &items)
            }
        };
        element.set_property(name.clone(), property);
    }
    Ok(element)
}

fn parse_scalar(token: &str, t: &ScalarType, name: &str) -> Result<Property, String> {
    let bad = || format!("value {token:?} of `{name}` is not a valid {t:?}");
    Ok(match t {
        ScalarType::Char => Property::Char(token.parse().map_err(|_| bad())?),
        ScalarType::UChar => Property::UChar(token.parse().map_err(|_| bad())?),
        ScalarType::Short => Property::Short(token.parse().map_err(|_| bad())?),
        ScalarType::UShort => Property::UShort(token.parse().map_err(|_| bad())?),
        ScalarType::Int => Property::Int(token.parse().map_err(|_| bad())?),
        ScalarType::UInt => Property::UInt(token.parse().map_err(|_| bad())?),
        ScalarType::Float => Property::Float(token.parse().map_err(|_| bad())?),
        ScalarType::Double => Property::Double(token.parse().map_err(|_| bad())?),
    })
}

/// Collects parsed scalars into the matching list property (lists are read past, not used).
fn list_property(t: &ScalarType, items: &[Property]) -> Property {
    let f = |p: &Property| as_f64(p).unwrap_or(0.0);
    match t {
        ScalarType::Char => Property::ListChar(items.iter().map(|p| f(p) as i8).collect()),
        ScalarType::UChar => Property::ListUChar(items.iter().map(|p| f(p) as u8).collect()),
        ScalarType::Short => Property::ListShort(items.iter().map(|p| f(p) as i16).collect()),
        ScalarType::UShort => Property::ListUShort(items.iter().map(|p| f(p) as u16).collect()),
        ScalarType::Int => Property::ListInt(items.iter().map(|p| f(p) as i32).collect()),
        ScalarType::UInt => Property::ListUInt(items.iter().map(|p| f(p) as u32).collect()),
        ScalarType::Float => Property::ListFloat(items.iter().map(|p| f(p) as f32).collect()),
        ScalarType::Double => Property::ListDouble(items.iter().map(f).collect()),
    }
}

fn first_line(s: &str) -> String {
    s.lines().next().unwrap_or_default().trim().to_string()
}

fn read_header<R: BufRead>(path: &Path, reader: &mut R) -> Result<Header, ReadError> {
    // Check the magic number ourselves so that a non-PLY file gets a plain answer.
    let buf = reader
        .fill_buf()
        .map_err(|e| ReadError::new(path, ReadErrorKind::Io(e)))?;
    if !buf.starts_with(b"ply") {
        return Err(ReadError::new(path, ReadErrorKind::WrongFormat("PLY")));
    }
    let parser = Parser::<DefaultElement>::new();
    parser.read_header(reader).map_err(|e| {
        let kind = if e.kind() == ErrorKind::UnexpectedEof || e.to_string().contains("end of file")
        {
            ReadErrorKind::Truncated("header has no end_header line".into())
        } else if e.kind() == ErrorKind::InvalidData {
            ReadErrorKind::WrongFormat("PLY")
        } else {
            ReadErrorKind::Invalid(format!("bad header: {}", first_line(&e.to_string())))
        };
        ReadError::new(path, kind)
    })
}

/// One vertex to write.
struct OutVertex<'a> {
    cloud: &'a PointCloud,
    index: usize,
}

impl PropertyAccess for OutVertex<'_> {
    fn new() -> Self {
        unreachable!("OutVertex is only written, never parsed")
    }

    fn get_double(&self, name: &String) -> Option<f64> {
        let p = self.cloud.points[self.index];
        match name.as_str() {
            "x" => Some(p.x),
            "y" => Some(p.y),
            "z" => Some(p.z),
            _ => None,
        }
    }

    fn get_float(&self, name: &String) -> Option<f32> {
        let n = self.cloud.normals.as_ref().map(|n| n[self.index]);
        match (name.as_str(), n) {
            ("nx", Some(n)) => Some(n.x as f32),
            ("ny", Some(n)) => Some(n.y as f32),
            ("nz", Some(n)) => Some(n.z as f32),
            ("intensity", _) => self.cloud.intensity.as_ref().map(|i| i[self.index]),
            _ => None,
        }
    }

    fn get_uchar(&self, name: &String) -> Option<u8> {
        let c = self.cloud.colors.as_ref()?[self.index];
        match name.as_str() {
            "red" => Some(c[0]),
            "green" => Some(c[1]),
            "blue" => Some(c[2]),
            _ => None,
        }
    }
}

/// Writes a cloud as binary little-endian PLY (x, y, z as double; nx, ny, nz float; red, green,
/// blue uchar; intensity float), atomically.
///
/// # Errors
///
/// [`WriteError`] naming the file; also when an attribute vector's length differs from the
/// number of points.
pub fn write_binary(path: &Path, cloud: &PointCloud) -> Result<(), WriteError> {
    let n = cloud.points.len();
    let lengths_ok = cloud.normals.as_ref().is_none_or(|v| v.len() == n)
        && cloud.colors.as_ref().is_none_or(|v| v.len() == n)
        && cloud.intensity.as_ref().is_none_or(|v| v.len() == n);
    if !lengths_ok {
        return Err(WriteError::new(
            path,
            std::io::Error::new(
                ErrorKind::InvalidInput,
                "attribute count differs from point count",
            ),
        ));
    }
    let mut header = Header::new();
    header.encoding = Encoding::BinaryLittleEndian;
    header.comments.push("written by pipemeasure".into());
    let mut vertex = ElementDef::new("vertex".into());
    vertex.count = n;
    let scalar = |name: &str, t: ScalarType| PropertyDef::new(name.into(), PropertyType::Scalar(t));
    for axis in ["x", "y", "z"] {
        vertex.properties.add(scalar(axis, ScalarType::Double));
    }
    if cloud.normals.is_some() {
        for axis in ["nx", "ny", "nz"] {
            vertex.properties.add(scalar(axis, ScalarType::Float));
        }
    }
    if cloud.colors.is_some() {
        for c in ["red", "green", "blue"] {
            vertex.properties.add(scalar(c, ScalarType::UChar));
        }
    }
    if cloud.intensity.is_some() {
        vertex
            .properties
            .add(scalar("intensity", ScalarType::Float));
    }
    header.elements.add(vertex.clone());
    write_atomic(path, |w| {
        let writer = Writer::<OutVertex<'_>>::new();
        writer.write_header(w, &header)?;
        for index in 0..n {
            writer.write_little_endian_element(w, &OutVertex { cloud, index }, &vertex)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    #[test]
    fn ascii_with_nan_normals_and_colours() {
        let dir = tempfile::tempdir().unwrap();
        let text = "ply\nformat ascii 1.0\ncomment hi\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3 0 0 1 10 20 30\nnan .5 0 0 0 1 1 1 1\n-1.5 2.25 1E3 1 0 0 255 0 7\n3 0 1 2\n";
        let p = write(dir.path(), "a.ply", text.as_bytes());
        let r = read(&p).unwrap();
        assert_eq!(r.vertices_in_file, 3);
        assert_eq!(r.skipped_non_finite, 1);
        assert_eq!(
            r.cloud.points,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-1.5, 2.25, 1000.0)]
        );
        assert_eq!(r.cloud.colors, Some(vec![[10, 20, 30], [255, 0, 7]]));
        assert_eq!(r.cloud.normals.unwrap()[1], Vector3::new(1.0, 0.0, 0.0));
        assert_eq!(r.cloud.intensity, None);
    }

    /// Builds a binary PLY by hand (independently of the writer).
    fn binary(big_endian: bool, n: usize, truncate: usize) -> Vec<u8> {
        let fmt = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut b = format!("ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\nproperty float intensity\nend_header\n").into_bytes();
        for k in 0..n {
            for v in [k as f64, -(k as f64), 0.5] {
                b.extend(if big_endian {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                });
            }
            let i = k as f32 * 2.0;
            b.extend(if big_endian {
                i.to_be_bytes()
            } else {
                i.to_le_bytes()
            });
        }
        b.truncate(b.len() - truncate);
        b
    }

    #[test]
    fn binary_both_endians_doubles_and_intensity() {
        let dir = tempfile::tempdir().unwrap();
        for big in [false, true] {
            let p = write(dir.path(), "b.ply", &binary(big, 4, 0));
            let r = read(&p).unwrap();
            assert_eq!(r.cloud.len(), 4);
            assert_eq!(r.cloud.points[3], Point3::new(3.0, -3.0, 0.5));
            assert_eq!(r.cloud.intensity.as_ref().unwrap()[2], 4.0);
        }
    }

    #[test]
    fn truncated_file_says_how_far_it_got() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "t.ply", &binary(false, 10, 20));
        let e = read(&p).unwrap_err().to_string();
        assert!(
            e.contains("t.ply") && e.contains("ends after 9 of 10 vertex"),
            "{e}"
        );
        let p = write(dir.path(), "t2.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n");
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains("ends after 1 of 3 vertex"), "{e}");
    }

    #[test]
    fn header_without_xyz_or_not_ply_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "noz.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n");
        let e = read(&p).unwrap_err().to_string();
        assert!(
            e.contains("noz.ply") && e.contains("no `z` property"),
            "{e}"
        );
        let p = write(dir.path(), "x.ply", b"\x89PNG\r\n\x1a\n garbage");
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains("not a PLY file"), "{e}");
        let p = write(
            dir.path(),
            "h.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
        );
        assert!(read(&p).is_err());
        let e = read(Path::new("/nonexistent.ply")).unwrap_err().to_string();
        assert!(e.contains("/nonexistent.ply: not found"), "{e}");
    }

    #[test]
    fn write_then_read_round_trips_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let cloud = PointCloud {
            points: vec![
                Point3::new(512_345.123_456_789, 5_678_901.5, 1e-9),
                Point3::new(-1.0, 0.0, 2.0),
            ],
            normals: Some(vec![
                Vector3::new(0.0, 0.0, 1.0),
                Vector3::new(1.0, 0.0, 0.0),
            ]),
            colors: Some(vec![[1, 2, 3], [250, 251, 252]]),
            intensity: Some(vec![0.25, 7.0]),
        };
        let p = dir.path().join("w.ply");
        write_binary(&p, &cloud).unwrap();
        let back = read(&p).unwrap();
        assert_eq!(back.cloud, cloud);
        assert!(
            std::fs::read(&p)
                .unwrap()
                .starts_with(b"ply\nformat binary_little_endian 1.0\n")
        );
    }
}
