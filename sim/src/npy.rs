//! A reader for the NumPy formats the bundles use: C-ordered little-endian float64 and float32
//! 2-D arrays, and uint8 arrays of any shape (camera frames).
//!
//! The exporters write `init_states.npy` (and the ALOHA-sim reference episodes) with `np.save`,
//! which notebooks read directly; a full `.npy` crate would add a dependency for ~50 lines.

use std::path::Path;

/// A row-major 2-D float64 array.
#[derive(Debug, Clone, PartialEq)]
pub struct Array2 {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f64>,
}

impl Array2 {
    pub fn row(&self, i: usize) -> &[f64] {
        &self.data[i * self.cols..(i + 1) * self.cols]
    }
}

/// Read a `<f8`, C-order, 2-D `.npy` file (format versions 1 and 2).
pub fn read_f64_2d(path: &Path) -> Result<Array2, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    parse_f64_2d(&bytes)
}

pub fn parse_f64_2d(bytes: &[u8]) -> Result<Array2, String> {
    let (shape, body) = parse(bytes, "<f8")?;
    let [rows, cols] = shape[..] else {
        return Err(format!("expected a 2-D array, shape is {shape:?}"));
    };
    let data = body.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect();
    Ok(Array2 { rows, cols, data })
}

/// Read a `<f4`, C-order, 2-D `.npy` file: `(rows, cols, values)` (actions as policies send them).
pub fn read_f32_2d(path: &Path) -> Result<(usize, usize, Vec<f32>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let (shape, body) = parse(&bytes, "<f4")?;
    let [rows, cols] = shape[..] else {
        return Err(format!("expected a 2-D array, shape is {shape:?}"));
    };
    Ok((rows, cols, body.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()))
}

/// Read a `|u1` (uint8), C-order `.npy` file of any shape: `(shape, bytes)` (camera frames).
pub fn read_u8(path: &Path) -> Result<(Vec<usize>, Vec<u8>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let (shape, body) = parse(&bytes, "|u1")?;
    Ok((shape, body.to_vec()))
}

/// The shape and data bytes of a C-ordered `.npy` file whose dtype is `descr`.
fn parse<'a>(bytes: &'a [u8], descr: &str) -> Result<(Vec<usize>, &'a [u8]), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy file (bad magic)".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("truncated .npy header".into());
            }
            (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12)
        }
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let header = std::str::from_utf8(bytes.get(start..start + header_len).ok_or("truncated .npy header")?)
        .map_err(|_| "non-UTF-8 .npy header")?;
    if !header.contains(&format!("'descr': '{descr}'")) {
        return Err(format!("expected {descr} data, header is {header}"));
    }
    if header.contains("'fortran_order': True") {
        return Err("expected C-ordered data".into());
    }
    let shape = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| format!("no shape in header {header}"))?;
    let dims: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|e| format!("bad shape {shape}: {e}")))
        .collect::<Result<_, _>>()?;
    let body = &bytes[start + header_len..];
    let item = descr[2..].parse::<usize>().map_err(|_| format!("unsupported dtype {descr}"))?;
    let need = dims.iter().product::<usize>() * item;
    if body.len() != need {
        return Err(format!("data has {} bytes, shape ({shape}) needs {need}", body.len()));
    }
    Ok((dims, body))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(header: &str, data: &[f64]) -> Vec<u8> {
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend((h.len() as u16).to_le_bytes());
        out.extend(h.as_bytes());
        for x in data {
            out.extend(x.to_le_bytes());
        }
        out
    }

    #[test]
    fn reads_a_2d_float64_array_and_rejects_other_layouts() {
        let ok = npy("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", &[1., 2., 3., 4., 5., 6.]);
        let a = parse_f64_2d(&ok).unwrap();
        assert_eq!((a.rows, a.cols), (2, 3));
        assert_eq!(a.row(1), &[4., 5., 6.]);
        let f32s = npy("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }", &[1., 2., 3.]);
        assert!(parse_f64_2d(&f32s).unwrap_err().contains("<f8"));
        let short = npy("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", &[1., 2.]);
        assert!(parse_f64_2d(&short).unwrap_err().contains("needs 48"));
        assert!(parse_f64_2d(b"garbage").is_err());
    }
}
