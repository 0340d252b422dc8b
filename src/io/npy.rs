//! A tiny NumPy `.npy` (format 1.0/2.0/3.0) writer and reader for the few dtypes the project uses: little-endian
//! `f32`, `u8`, `i16` and `u16`, C order. Written files load with `numpy.load` alone.

use std::io::Write;
use std::path::Path;

/// Errors reading or writing `.npy` data.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    /// The bytes are not a `.npy` file or use a feature this reader does not support.
    #[error("not a supported .npy array: {0}")]
    Format(String),
    /// The shape does not match the number of elements given.
    #[error("shape {shape:?} needs {expected} elements but {got} were given")]
    ShapeMismatch {
        /// The shape.
        shape: Vec<usize>,
        /// Elements the shape implies.
        expected: usize,
        /// Elements provided.
        got: usize,
    },
    /// An I/O error.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
    /// Reading a file failed: which file, and why.
    #[error("{path}: {source}")]
    File {
        /// The file.
        path: std::path::PathBuf,
        /// The cause.
        source: Box<NpyError>,
    },
}

/// The element data of an array, by dtype.
#[derive(Clone, Debug, PartialEq)]
pub enum NpyData {
    /// `<f4`
    F32(Vec<f32>),
    /// `|u1`
    U8(Vec<u8>),
    /// `<i2`
    I16(Vec<i16>),
    /// `<u2`
    U16(Vec<u16>),
}

impl NpyData {
    fn len(&self) -> usize {
        match self {
            NpyData::F32(v) => v.len(),
            NpyData::U8(v) => v.len(),
            NpyData::I16(v) => v.len(),
            NpyData::U16(v) => v.len(),
        }
    }

    fn descr(&self) -> &'static str {
        match self {
            NpyData::F32(_) => "<f4",
            NpyData::U8(_) => "|u1",
            NpyData::I16(_) => "<i2",
            NpyData::U16(_) => "<u2",
        }
    }
}

/// An n-dimensional array in C (row-major) order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// Dimensions, outermost first.
    pub shape: Vec<usize>,
    /// The elements.
    pub data: NpyData,
}

impl NpyArray {
    /// An array, checking that the shape matches the element count.
    pub fn new(shape: Vec<usize>, data: NpyData) -> Result<Self, NpyError> {
        let expected = shape.iter().product::<usize>();
        if expected != data.len() {
            return Err(NpyError::ShapeMismatch { shape, expected, got: data.len() });
        }
        Ok(Self { shape, data })
    }

    /// Serialises to `.npy` bytes (format 1.0, or 2.0 when the header does not fit 65535 bytes).
    pub fn to_bytes(&self) -> Vec<u8> {
        let shape = match self.shape.len() {
            1 => format!("({},)", self.shape[0]),
            _ => format!("({})", self.shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
        };
        let dict = format!("{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}", self.data.descr(), shape);
        // magic(6) + version(2) + header length (2 or 4) + dict + padding + '\n' must be a multiple of 64.
        let (version, len_bytes) = if dict.len() + 11 < 65_000 { (1u8, 2usize) } else { (2u8, 4usize) };
        let unpadded = 6 + 2 + len_bytes + dict.len() + 1;
        let pad = (64 - unpadded % 64) % 64;
        let header_len = dict.len() + pad + 1;
        let mut out = Vec::with_capacity(unpadded + pad + self.data.len() * 4);
        out.extend_from_slice(b"\x93NUMPY");
        out.extend_from_slice(&[version, 0]);
        if len_bytes == 2 {
            out.extend_from_slice(&(header_len as u16).to_le_bytes());
        } else {
            out.extend_from_slice(&(header_len as u32).to_le_bytes());
        }
        out.extend_from_slice(dict.as_bytes());
        out.extend(std::iter::repeat_n(b' ', pad));
        out.push(b'\n');
        // Fixed-size element copies into a pre-sized buffer (much faster than byte-wise pushes).
        fn put<const K: usize, T: Copy>(out: &mut Vec<u8>, v: &[T], f: impl Fn(T) -> [u8; K]) {
            let start = out.len();
            out.resize(start + v.len() * K, 0);
            for (dst, &x) in out[start..].chunks_exact_mut(K).zip(v) {
                dst.copy_from_slice(&f(x));
            }
        }
        match &self.data {
            NpyData::F32(v) => put(&mut out, v, f32::to_le_bytes),
            NpyData::U8(v) => out.extend_from_slice(v),
            NpyData::I16(v) => put(&mut out, v, i16::to_le_bytes),
            NpyData::U16(v) => put(&mut out, v, u16::to_le_bytes),
        }
        out
    }

    /// Parses `.npy` bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, NpyError> {
        let fmt = |m: &str| NpyError::Format(m.to_string());
        if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
            return Err(fmt("missing the \\x93NUMPY magic"));
        }
        let (header_start, header_len): (usize, usize) = match bytes[6] {
            1 => (10, u16::from_le_bytes([bytes[8], bytes[9]]) as usize),
            2 | 3 if bytes.len() >= 12 => (12, u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize),
            v => return Err(NpyError::Format(format!("unsupported format version {v}"))),
        };
        let body_start =
            header_start.checked_add(header_len).filter(|&e| e <= bytes.len()).ok_or(fmt("truncated header"))?;
        let header = std::str::from_utf8(&bytes[header_start..body_start]).map_err(|_| fmt("header is not text"))?;
        let descr = dict_value(header, "descr").ok_or(fmt("header has no 'descr'"))?;
        let descr = descr.trim().trim_matches(|c| c == '\'' || c == '"');
        let fortran = dict_value(header, "fortran_order").ok_or(fmt("header has no 'fortran_order'"))?;
        if fortran.trim().starts_with("True") {
            return Err(fmt("Fortran-order arrays are not supported"));
        }
        let shape_text = dict_value(header, "shape").ok_or(fmt("header has no 'shape'"))?;
        let shape_text = shape_text.trim();
        let inner =
            shape_text.strip_prefix('(').and_then(|s| s.find(')').map(|e| &s[..e])).ok_or(fmt("malformed shape"))?;
        let shape = inner
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<usize>().map_err(|_| NpyError::Format(format!("bad dimension {s:?}"))))
            .collect::<Result<Vec<_>, _>>()?;
        let count = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d)).ok_or(fmt("shape overflows"))?;
        let body = &bytes[body_start..];
        let need = |size: usize| -> Result<&[u8], NpyError> {
            let n = count.checked_mul(size).ok_or(fmt("shape overflows"))?;
            body.get(..n).ok_or_else(|| NpyError::Format(format!("truncated data: {} of {n} bytes", body.len())))
        };
        let data = match descr {
            "<f4" => {
                NpyData::F32(need(4)?.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
            }
            "|u1" | "<u1" | "u1" => NpyData::U8(need(1)?.to_vec()),
            "<i2" => NpyData::I16(need(2)?.chunks_exact(2).map(|c| i16::from_le_bytes([c[0], c[1]])).collect()),
            "<u2" => NpyData::U16(need(2)?.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect()),
            other => return Err(NpyError::Format(format!("unsupported dtype {other:?}"))),
        };
        Ok(Self { shape, data })
    }

    /// Writes the array to `path` atomically (temporary file in the same folder, then rename).
    pub fn write(&self, path: &Path) -> Result<(), NpyError> {
        write_atomic(path, &self.to_bytes())?;
        Ok(())
    }

    /// Reads an array from a file; errors name the file.
    pub fn read(path: &Path) -> Result<Self, NpyError> {
        let in_file = |e: NpyError| NpyError::File { path: path.to_path_buf(), source: Box::new(e) };
        let bytes = std::fs::read(path).map_err(|e| in_file(e.into()))?;
        Self::from_bytes(&bytes).map_err(in_file)
    }
}

/// The text after `'key':` in a Python dict literal, up to the next top-level comma or the closing brace.
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pat_single = format!("'{key}'");
    let pat_double = format!("\"{key}\"");
    let at = header
        .find(&pat_single)
        .map(|i| i + pat_single.len())
        .or_else(|| header.find(&pat_double).map(|i| i + pat_double.len()))?;
    let rest = header[at..].trim_start().strip_prefix(':')?;
    let mut depth = 0i32;
    for (i, ch) in rest.char_indices() {
        match ch {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(&rest[..i]),
            _ => {}
        }
    }
    Some(rest)
}

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a reader never sees a
/// half-written file and a failure leaves nothing behind.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let mut tmp = tempfile::Builder::new().prefix(".r2human-").suffix(".part").tempfile_in(dir)?;
    tmp.write_all(bytes)?;
    set_readable(tmp.as_file())?;
    tmp.as_file().sync_data().ok();
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// Gives a file the usual `rw-r--r--` permissions (temporary files are created owner-only).
pub fn set_readable(file: &std::fs::File) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        file.set_permissions(std::fs::Permissions::from_mode(0o644))?;
    }
    #[cfg(not(unix))]
    let _ = file;
    Ok(())
}

/// Writes a float32 array of the given shape to `path` (atomically).
pub fn write_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<(), NpyError> {
    NpyArray::new(shape.to_vec(), NpyData::F32(data.to_vec()))?.write(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_all_dtypes() {
        let arrays = [
            NpyArray::new(vec![2, 3], NpyData::F32(vec![0.0, -1.5, 2.25, f32::MAX, 1e-30, 7.0])).unwrap(),
            NpyArray::new(vec![4], NpyData::U8(vec![0, 1, 254, 255])).unwrap(),
            NpyArray::new(vec![1, 2, 2], NpyData::I16(vec![-32768, -1, 0, 32767])).unwrap(),
            NpyArray::new(vec![0, 3], NpyData::U16(vec![])).unwrap(),
        ];
        for a in arrays {
            let bytes = a.to_bytes();
            // The header (up to and including '\n') is 64-byte aligned as the format requires.
            let header_end = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
            assert_eq!(header_end % 64, 0);
            assert_eq!(NpyArray::from_bytes(&bytes).unwrap(), a);
        }
    }

    #[test]
    fn header_matches_numpy_layout() {
        let a = NpyArray::new(vec![2, 2, 3], NpyData::F32(vec![0.5; 12])).unwrap();
        let bytes = a.to_bytes();
        let end = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
        assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]) as usize, end - 10);
        let text = String::from_utf8_lossy(&bytes[10..end]);
        assert!(text.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2, 3), }"), "{text}");
        assert_eq!(bytes.len(), end + 12 * 4);
        assert_eq!(&bytes[end..end + 4], &0.5f32.to_le_bytes());
        let one_d = NpyArray::new(vec![3], NpyData::U8(vec![1, 2, 3])).unwrap().to_bytes();
        assert!(String::from_utf8_lossy(&one_d).contains("'shape': (3,)"));
    }

    #[test]
    fn bad_input_is_an_error() {
        assert!(NpyArray::new(vec![2, 2], NpyData::F32(vec![1.0])).is_err());
        assert!(NpyArray::from_bytes(b"not numpy").is_err());
        let mut bytes = NpyArray::new(vec![8], NpyData::F32(vec![1.0; 8])).unwrap().to_bytes();
        bytes.truncate(bytes.len() - 3);
        assert!(matches!(NpyArray::from_bytes(&bytes), Err(NpyError::Format(_))));
        let mut bytes = NpyArray::new(vec![1], NpyData::F32(vec![1.0])).unwrap().to_bytes();
        bytes[8] = 0xff; // header length past the end
        bytes[9] = 0xff;
        assert!(NpyArray::from_bytes(&bytes).is_err());
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("short.npy");
        std::fs::write(&p, b"\x93NUMPY").unwrap();
        let e = NpyArray::read(&p).unwrap_err().to_string();
        assert!(e.contains("short.npy") && e.contains("magic"), "{e}");
        let e = NpyArray::read(&dir.path().join("gone.npy")).unwrap_err().to_string();
        assert!(e.contains("gone.npy"), "{e}");
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        write_f32(&p, &[2], &[1.0, 2.0]).unwrap();
        write_f32(&p, &[1], &[3.0]).unwrap();
        assert_eq!(NpyArray::read(&p).unwrap().data, NpyData::F32(vec![3.0]));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
