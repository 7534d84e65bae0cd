//! The wire format between the pipeline and its Python policy host (`policies/python/
//! libero_eval_host.py` is the other end): `u32 LE` header length, `u64 LE` blob length, the
//! header as UTF-8 JSON, the blob. `header["arrays"]` maps each array's name to `{"dtype",
//! "shape", "offset"}` into the blob (C order, little-endian).
//!
//! Why not MessagePack, which the remote clients speak: the host must run in any interpreter a
//! user names (a JAX venv, say) with nothing but NumPy, and JSON plus `np.frombuffer` is in every
//! one of them; images go as raw bytes, no codec on either side.

use serde_json::{Map, Value, json};
use std::collections::BTreeMap;
use std::io::{self, Read};

/// Longest header accepted (a host's describe() with a checkpoint's file hashes is a few KB).
const MAX_HEADER: u32 = 16 << 20;
/// Largest blob accepted (a batch of 64 episodes' two 360² cameras is ~50 MB).
const MAX_BLOB: u64 = 4 << 30;

/// Element types that cross the pipe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    U8,
    F32,
    F64,
    I64,
}

impl Dtype {
    fn size(self) -> usize {
        match self {
            Dtype::U8 => 1,
            Dtype::F32 => 4,
            Dtype::F64 | Dtype::I64 => 8,
        }
    }

    /// NumPy's `dtype.str` without the byte-order mark.
    fn name(self) -> &'static str {
        match self {
            Dtype::U8 => "u1",
            Dtype::F32 => "f4",
            Dtype::F64 => "f8",
            Dtype::I64 => "i8",
        }
    }

    fn parse(s: &str) -> Result<Self, String> {
        match s.trim_start_matches(['<', '|', '=']) {
            "u1" => Ok(Dtype::U8),
            "f4" => Ok(Dtype::F32),
            "f8" => Ok(Dtype::F64),
            "i8" => Ok(Dtype::I64),
            other => Err(format!("dtype {other:?} (expected u1, f4, f8 or i8)")),
        }
    }
}

/// One array: its bytes in C order, little-endian.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

impl Array {
    pub fn u8(shape: Vec<usize>, data: Vec<u8>) -> Self {
        Array { dtype: Dtype::U8, shape, data }
    }

    pub fn f64(shape: Vec<usize>, values: &[f64]) -> Self {
        Array { dtype: Dtype::F64, shape, data: values.iter().flat_map(|v| v.to_le_bytes()).collect() }
    }

    pub fn f32(shape: Vec<usize>, values: &[f32]) -> Self {
        Array { dtype: Dtype::F32, shape, data: values.iter().flat_map(|v| v.to_le_bytes()).collect() }
    }

    /// The values of a float32 array.
    pub fn to_f32(&self) -> Result<Vec<f32>, String> {
        match self.dtype {
            Dtype::F32 => Ok(self.data.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect()),
            other => Err(format!("expected float32, got {}", other.name())),
        }
    }
}

/// One message: a JSON header and named arrays.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frame {
    pub header: Map<String, Value>,
    pub arrays: BTreeMap<String, Array>,
}

impl Frame {
    pub fn new(header: Value) -> Self {
        Frame { header: header.as_object().cloned().unwrap_or_default(), arrays: BTreeMap::new() }
    }

    /// `header["op"]`.
    pub fn op(&self) -> &str {
        self.header.get("op").and_then(Value::as_str).unwrap_or("")
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut header = self.header.clone();
        let (mut meta, mut offset) = (Map::new(), 0usize);
        for (name, a) in &self.arrays {
            meta.insert(name.clone(), json!({"dtype": a.dtype.name(), "shape": a.shape, "offset": offset}));
            offset += a.data.len();
        }
        header.insert("arrays".into(), Value::Object(meta));
        let h = serde_json::to_vec(&header).expect("a JSON map serialises");
        let mut out = Vec::with_capacity(12 + h.len() + offset);
        out.extend_from_slice(&(h.len() as u32).to_le_bytes());
        out.extend_from_slice(&(offset as u64).to_le_bytes());
        out.extend_from_slice(&h);
        for a in self.arrays.values() {
            out.extend_from_slice(&a.data);
        }
        out
    }

    /// The next frame, `Ok(None)` at a clean end of input; a malformed frame is an `InvalidData`
    /// error naming what is wrong.
    pub fn read_from(r: &mut impl Read) -> io::Result<Option<Frame>> {
        let mut lengths = [0u8; 12];
        match r.read_exact(&mut lengths[..1]) {
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => return Ok(None),
            other => other?,
        }
        r.read_exact(&mut lengths[1..])?;
        let header_len = u32::from_le_bytes(lengths[..4].try_into().unwrap());
        let blob_len = u64::from_le_bytes(lengths[4..].try_into().unwrap());
        let bad = |detail: String| io::Error::new(io::ErrorKind::InvalidData, detail);
        if header_len > MAX_HEADER || blob_len > MAX_BLOB {
            return Err(bad(format!(
                "a frame announces a {header_len}-byte header and a {blob_len}-byte blob (something other than the host wrote on its stdout?)"
            )));
        }
        let mut h = vec![0u8; header_len as usize];
        r.read_exact(&mut h)?;
        let mut blob = vec![0u8; blob_len as usize];
        r.read_exact(&mut blob)?;
        let mut header: Map<String, Value> = match serde_json::from_slice(&h) {
            Ok(Value::Object(m)) => m,
            Ok(other) => return Err(bad(format!("the frame header is not a JSON map: {other}"))),
            Err(e) => return Err(bad(format!("the frame header is not JSON: {e}"))),
        };
        let mut arrays = BTreeMap::new();
        if let Some(meta) = header.remove("arrays") {
            let meta = meta.as_object().cloned().ok_or_else(|| bad("header.arrays is not a map".into()))?;
            for (name, m) in meta {
                let array = decode_array(&m, &blob).map_err(|e| bad(format!("array {name:?}: {e}")))?;
                arrays.insert(name, array);
            }
        }
        Ok(Some(Frame { header, arrays }))
    }
}

fn decode_array(m: &Value, blob: &[u8]) -> Result<Array, String> {
    let dtype = Dtype::parse(m.get("dtype").and_then(Value::as_str).ok_or("no dtype")?)?;
    let shape: Vec<usize> = m
        .get("shape")
        .and_then(Value::as_array)
        .ok_or("no shape")?
        .iter()
        .map(|d| d.as_u64().map(|d| d as usize).ok_or("a dimension is not a non-negative integer"))
        .collect::<Result<_, _>>()?;
    let offset = m.get("offset").and_then(Value::as_u64).ok_or("no offset")? as usize;
    let count = shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).ok_or("shape overflows")?;
    let end = count.checked_mul(dtype.size()).and_then(|n| n.checked_add(offset)).ok_or("size overflows")?;
    if end > blob.len() {
        return Err(format!("bytes {offset}..{end} lie past the blob's {} bytes", blob.len()));
    }
    Ok(Array { dtype, shape, data: blob[offset..end].to_vec() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_reads_back_as_written() {
        let mut f = Frame::new(json!({"op": "act", "episodes": [{"task": "open the drawer", "seed": 7}]}));
        f.arrays.insert("agentview".into(), Array::u8(vec![1, 2, 2, 3], (0..12).collect()));
        f.arrays.insert("eef_pos".into(), Array::f64(vec![1, 3], &[0.5, -1.25, 3.0]));
        let bytes = f.encode();
        let back = Frame::read_from(&mut bytes.as_slice()).unwrap().unwrap();
        assert_eq!(back, f);
        assert!(Frame::read_from(&mut &b""[..]).unwrap().is_none());
    }

    #[test]
    fn malformed_frames_are_errors_not_allocations() {
        let mut huge = Vec::from(u32::MAX.to_le_bytes());
        huge.extend_from_slice(&0u64.to_le_bytes());
        let e = Frame::read_from(&mut huge.as_slice()).unwrap_err();
        assert!(e.to_string().contains("something other than the host"), "{e}");
        let mut past = Frame::new(json!({"op": "actions"}));
        past.arrays.insert("actions".into(), Array::f32(vec![1, 1, 7], &[0.0; 7]));
        let mut bytes = past.encode();
        bytes.truncate(bytes.len() - 4);
        assert!(Frame::read_from(&mut bytes.as_slice()).is_err());
    }
}
