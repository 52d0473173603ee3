//! The PLY header, parsed here rather than by a dependency: ply-rs's grammar panicked on
//! integers beyond `u64` (`element vertex 99999999999999999999999`), merged a property declared
//! twice into one (so `x y z x` rotated the coordinates) and let an element declared twice
//! replace the first, and it required the whole header to be UTF-8. This parser reads bytes,
//! ignores the text of `comment` and `obj_info` lines (any bytes), and refuses every
//! inconsistency with the line and the field.

use std::io::BufRead;
use std::path::Path;

use crate::io::error::{ReadError, ReadErrorKind};

/// A header longer than this is refused (real headers are a few hundred bytes; the limit keeps
/// a file without `end_header` from being read whole as header).
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// How the body is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// One element per line, values separated by whitespace.
    Ascii,
    /// Packed little-endian values.
    BinaryLittleEndian,
    /// Packed big-endian values.
    BinaryBigEndian,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    /// `char` / `int8`.
    I8,
    /// `uchar` / `uint8`.
    U8,
    /// `short` / `int16`.
    I16,
    /// `ushort` / `uint16`.
    U16,
    /// `int` / `int32`.
    I32,
    /// `uint` / `uint32`.
    U32,
    /// `float` / `float32`.
    F32,
    /// `double` / `float64`.
    F64,
}

impl Scalar {
    /// The type of a header name (both spellings of the PLY specification).
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// The name pipemeasure writes.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }

    /// Bytes in a binary body.
    #[must_use]
    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Whether the type is an integer (a list length must be).
    #[must_use]
    pub fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

/// A property's type: one value, or a list of values preceded by its length.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// One value.
    Scalar(Scalar),
    /// `property list COUNT ITEM NAME`.
    List {
        /// Type of the length.
        count: Scalar,
        /// Type of the items.
        item: Scalar,
    },
}

/// A declared property.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Property {
    /// Its name.
    pub name: String,
    /// Its type.
    pub kind: Kind,
}

/// A declared element.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Element {
    /// Its name (`vertex`, `face`, …).
    pub name: String,
    /// How many the body holds, as declared.
    pub count: u64,
    /// Its properties, in file order.
    pub properties: Vec<Property>,
    /// The 1-based header line that declares it.
    pub line: usize,
}

impl Element {
    /// The position of a property by name.
    #[must_use]
    pub fn position(&self, name: &str) -> Option<usize> {
        self.properties.iter().position(|p| p.name == name)
    }

    /// Bytes of one element in a binary body when it has no list (`None` with a list).
    #[must_use]
    pub fn fixed_size(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(t) => Some(t.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    /// The fewest bytes one element can take in the body: in binary its scalars and list
    /// lengths; in ascii one character and one separator per value.
    #[must_use]
    pub fn min_bytes(&self, format: Format) -> u64 {
        match format {
            Format::Ascii => 2 * self.properties.len() as u64,
            _ => self
                .properties
                .iter()
                .map(|p| match p.kind {
                    Kind::Scalar(t) | Kind::List { count: t, .. } => t.size() as u64,
                })
                .sum(),
        }
    }
}

/// A parsed header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    /// The body's encoding.
    pub format: Format,
    /// The elements, in file order.
    pub elements: Vec<Element>,
    /// Lines in the header, `end_header` included (ascii body lines follow).
    pub lines: usize,
    /// Bytes in the header, `end_header` and its line break included.
    pub bytes: u64,
}

/// Reads the header from the start of `reader`, leaving it at the first byte of the body.
///
/// # Errors
///
/// [`ReadError`] naming `path` and the header line: not a PLY file, an unknown keyword or type,
/// a count that is not a number or beyond `u64`, an element or property declared twice, a
/// property outside an element, a list whose length is not an integer, no `format` line, no
/// `end_header` within [`MAX_HEADER_BYTES`].
pub fn read_header<R: BufRead>(path: &Path, reader: &mut R) -> Result<Header, ReadError> {
    let mut line_bytes = Vec::new();
    let mut bytes = 0u64;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 0usize;
    loop {
        line_bytes.clear();
        let budget = (MAX_HEADER_BYTES as u64).saturating_sub(bytes) + 1;
        let n = <&mut R as std::io::Read>::take(&mut *reader, budget)
            .read_until(b'\n', &mut line_bytes)
            .map_err(|e| ReadError::new(path, ReadErrorKind::Io(e)))?;
        line_no += 1;
        bytes += n as u64;
        let err = |kind| ReadError::at_line(path, line_no, kind);
        if n == 0 {
            return Err(if line_no == 1 {
                ReadError::new(path, ReadErrorKind::WrongFormat("PLY"))
            } else {
                err(ReadErrorKind::Truncated(
                    "the header has no end_header line".into(),
                ))
            });
        }
        if bytes > MAX_HEADER_BYTES as u64 {
            return Err(err(ReadErrorKind::Invalid(format!(
                "the header is longer than {MAX_HEADER_BYTES} bytes without an end_header line"
            ))));
        }
        if line_bytes.last() != Some(&b'\n') {
            return Err(err(ReadErrorKind::Truncated(
                "the header has no end_header line".into(),
            )));
        }
        let content = trim_line(&line_bytes);
        if line_no == 1 {
            if content != b"ply" {
                return Err(ReadError::new(path, ReadErrorKind::WrongFormat("PLY")));
            }
            continue;
        }
        let keyword = content.split(u8::is_ascii_whitespace).next().unwrap_or(b"");
        // Comments and object information are free text: any bytes, never parsed.
        if matches!(keyword, b"comment" | b"obj_info") || content.is_empty() {
            continue;
        }
        let Ok(text) = std::str::from_utf8(content) else {
            return Err(err(ReadErrorKind::Invalid(
                "a header line other than a comment holds bytes that are not text".into(),
            )));
        };
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words[0] {
            "format" => {
                if format.is_some() {
                    return Err(err(ReadErrorKind::Invalid("a second format line".into())));
                }
                if !elements.is_empty() {
                    return Err(err(ReadErrorKind::Invalid(
                        "the format line comes after an element".into(),
                    )));
                }
                format = Some(parse_format(&words, &err)?);
            }
            "element" => {
                let [_, name, count] = words[..] else {
                    return Err(err(ReadErrorKind::FieldCount {
                        expected: "`element NAME COUNT`: 3 words".into(),
                        found: words.len(),
                    }));
                };
                let count: u64 = count.parse().map_err(|_| {
                    err(ReadErrorKind::Field {
                        field: "element count",
                        value: count.to_string(),
                        expected: "a count from 0 to 18446744073709551615",
                    })
                })?;
                if let Some(first) = elements.iter().find(|e| e.name == name) {
                    return Err(err(ReadErrorKind::Invalid(format!(
                        "element `{name}` declared a second time (first on line {})",
                        first.line
                    ))));
                }
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                    line: line_no,
                });
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(err(ReadErrorKind::Invalid(
                        "a property before any element".into(),
                    )));
                };
                let property = parse_property(&words, &err)?;
                if element.position(&property.name).is_some() {
                    return Err(err(ReadErrorKind::Invalid(format!(
                        "property `{}` of element `{}` declared a second time",
                        property.name, element.name
                    ))));
                }
                element.properties.push(property);
            }
            "end_header" => {
                if words.len() != 1 {
                    return Err(err(ReadErrorKind::Invalid(
                        "words after end_header on its line".into(),
                    )));
                }
                let Some(format) = format else {
                    return Err(err(ReadErrorKind::Invalid(
                        "the header has no format line".into(),
                    )));
                };
                return Ok(Header {
                    format,
                    elements,
                    lines: line_no,
                    bytes,
                });
            }
            other => {
                return Err(err(ReadErrorKind::Invalid(format!(
                    "unknown header keyword `{}`",
                    other.chars().take(40).collect::<String>()
                ))));
            }
        }
    }
}

/// The line without its line break (`\n` or `\r\n`) and surrounding blanks.
fn trim_line(line: &[u8]) -> &[u8] {
    line.trim_ascii()
}

/// `format ascii|binary_little_endian|binary_big_endian 1.0`.
fn parse_format(
    words: &[&str],
    err: &dyn Fn(ReadErrorKind) -> ReadError,
) -> Result<Format, ReadError> {
    let [_, encoding, version] = words[..] else {
        return Err(err(ReadErrorKind::FieldCount {
            expected: "`format ENCODING 1.0`: 3 words".into(),
            found: words.len(),
        }));
    };
    let format = match encoding {
        "ascii" => Format::Ascii,
        "binary_little_endian" => Format::BinaryLittleEndian,
        "binary_big_endian" => Format::BinaryBigEndian,
        _ => {
            return Err(err(ReadErrorKind::Field {
                field: "format",
                value: encoding.chars().take(40).collect(),
                expected: "ascii, binary_little_endian or binary_big_endian",
            }));
        }
    };
    if !matches!(version, "1.0" | "1") {
        return Err(err(ReadErrorKind::Field {
            field: "format version",
            value: version.chars().take(40).collect(),
            expected: "1.0 (the only PLY version)",
        }));
    }
    Ok(format)
}

/// `property TYPE NAME` or `property list COUNT_TYPE ITEM_TYPE NAME`.
fn parse_property(
    words: &[&str],
    err: &dyn Fn(ReadErrorKind) -> ReadError,
) -> Result<Property, ReadError> {
    let scalar = |name: &str, field: &'static str| {
        Scalar::from_name(name).ok_or_else(|| {
            err(ReadErrorKind::Field {
                field,
                value: name.chars().take(40).collect(),
                expected: "a PLY type (char, uchar, short, ushort, int, uint, float, double)",
            })
        })
    };
    let (kind, name) = match words[..] {
        [_, "list", count, item, name] => {
            let count = scalar(count, "list length type")?;
            if !count.is_integer() {
                return Err(err(ReadErrorKind::Field {
                    field: "list length type",
                    value: count.name().into(),
                    expected: "an integer type",
                }));
            }
            (
                Kind::List {
                    count,
                    item: scalar(item, "list item type")?,
                },
                name,
            )
        }
        [_, t, name] if t != "list" => (Kind::Scalar(scalar(t, "property type")?), name),
        _ => {
            return Err(err(ReadErrorKind::FieldCount {
                expected: "`property TYPE NAME` (3 words) or `property list COUNT ITEM NAME` (5)"
                    .into(),
                found: words.len(),
            }));
        }
    };
    Ok(Property {
        name: name.to_string(),
        kind,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &[u8]) -> Result<Header, String> {
        read_header(Path::new("h.ply"), &mut &text[..]).map_err(|e| e.to_string())
    }

    #[test]
    fn a_full_header_parses_with_positions() {
        let h = parse(b"ply\r\nformat binary_big_endian 1.0\r\ncomment \xff\xfe not text\r\nelement vertex 3\r\nproperty float32 x\r\nproperty list uint8 int vertex_indices\r\nelement face 0\r\nend_header\r\nBODY").unwrap();
        assert_eq!(h.format, Format::BinaryBigEndian);
        assert_eq!(h.lines, 8);
        assert_eq!(h.bytes, 162);
        assert_eq!(h.elements.len(), 2);
        assert_eq!(h.elements[0].count, 3);
        assert_eq!(h.elements[0].line, 4);
        assert_eq!(
            h.elements[0].properties[1].kind,
            Kind::List {
                count: Scalar::U8,
                item: Scalar::I32
            }
        );
        assert_eq!(h.elements[0].min_bytes(Format::BinaryBigEndian), 5);
        assert_eq!(h.elements[0].fixed_size(), None);
        assert!(h.elements[1].properties.is_empty());
    }

    #[test]
    fn inconsistent_headers_name_the_line() {
        let cases: [(&[u8], &str); 10] = [
            (b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\n", "h.ply:3: field element count"),
            (b"ply\nformat ascii 99999999999999999999.0\n", "h.ply:2: field format version"),
            (b"ply\nformat ascii 1.0\nelement v 1\nproperty float x\nproperty float x\nend_header\n", "h.ply:5: property `x` of element `v` declared a second time"),
            (b"ply\nformat ascii 1.0\nelement v 1\nelement v 2\nend_header\n", "h.ply:4: element `v` declared a second time (first on line 3)"),
            (b"ply\nformat ascii 1.0\nproperty float x\n", "h.ply:3: a property before any element"),
            (b"ply\nformat ascii 1.0\nelement v 1\nproperty list float int i\n", "h.ply:4: field list length type"),
            (b"ply\nelement v 1\nend_header\n", "h.ply:3: the header has no format line"),
            (b"ply\nformat ascii 1.0\nelement v 1\n", "h.ply:4: file ends early"),
            (b"ply\nformat ascii 1.0\nelement \xff 1\n", "h.ply:3: a header line other than a comment"),
            (b"PNG\nformat ascii 1.0\n", "h.ply: not a PLY file"),
        ];
        for (text, want) in cases {
            let e = parse(text).unwrap_err();
            assert!(e.starts_with(want), "{e}\nwanted {want}");
        }
    }

    #[test]
    fn a_header_without_end_is_bounded() {
        let mut text = b"ply\nformat ascii 1.0\n".to_vec();
        text.extend(std::iter::repeat_n(b'a', MAX_HEADER_BYTES + 10));
        let e = parse(&text).unwrap_err();
        assert!(e.contains("longer than"), "{e}");
    }
}
