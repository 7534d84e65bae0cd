//! openpi's msgpack-numpy: NumPy arrays inside MessagePack, as `openpi_client.msgpack_numpy`
//! writes and reads them.
//!
//! The wire form of an array (`pack_array` in `packages/openpi-client/src/openpi_client/
//! msgpack_numpy.py`, adapted there from lebedov/msgpack-numpy without its pickle fallback):
//!
//! ```text
//! { b"__ndarray__": True, b"data": <bytes: arr.tobytes(), C order>, b"dtype": <str: arr.dtype.str, e.g. "<f4", "|u1">,
//!   b"shape": <array of ints: arr.shape> }
//! ```
//!
//! The four keys are MessagePack **bin** (Python `bytes`), not str: the reader (`unpack_array`,
//! an `object_hook`) tests `b"__ndarray__" in obj`, so a map with str keys arrives in Python as a
//! plain dict, not an array. `dtype` is a str, `data` is bin, `shape` an array. A NumPy scalar is
//! `{b"__npgeneric__": True, b"data": <item>, b"dtype": <str>}`. Object, void and complex dtypes
//! are refused by the Python side, and here.
//!
//! Everything else is plain MessagePack as `msgpack.Packer()` (1.x) writes it: Python str → str,
//! bytes → bin, tuple/list → array, dict → map. [`NdArray`] is our side of one array, the
//! [`Value`] tree (rmpv) keeps bin and str apart, which the format depends on.

use rmpv::Value;

/// Key marking a packed array (bin, as Python's `b"__ndarray__"`).
pub const NDARRAY_KEY: &[u8] = b"__ndarray__";
/// Key marking a packed NumPy scalar (bin).
pub const NPGENERIC_KEY: &[u8] = b"__npgeneric__";

/// An n-dimensional array in NumPy's terms: dtype string, shape, raw C-order bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct NdArray {
    /// NumPy's `dtype.str`: byte order (`<` little, `>` big, `|` not applicable), kind, item size.
    pub dtype: String,
    pub shape: Vec<usize>,
    /// `arr.tobytes()`: C order, the dtype's byte order.
    pub data: Vec<u8>,
}

/// A value that is not what the protocol says it should be.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct DecodeError(pub String);

fn err<T>(msg: impl Into<String>) -> Result<T, DecodeError> {
    Err(DecodeError(msg.into()))
}

impl NdArray {
    /// A float64 array (`"<f8"`), as NumPy holds robosuite's observations.
    pub fn from_f64(shape: &[usize], values: &[f64]) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), values.len());
        NdArray {
            dtype: "<f8".into(),
            shape: shape.to_vec(),
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    /// A float32 array (`"<f4"`).
    pub fn from_f32(shape: &[usize], values: &[f32]) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), values.len());
        NdArray {
            dtype: "<f4".into(),
            shape: shape.to_vec(),
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    /// A uint8 array (`"|u1"`), e.g. an (H, W, 3) image.
    pub fn from_u8(shape: &[usize], values: Vec<u8>) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), values.len());
        NdArray { dtype: "|u1".into(), shape: shape.to_vec(), data: values }
    }

    /// Number of elements (the product of the shape).
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The elements as f64, for float dtypes of either byte order (`f2` is not supported) and
    /// for integer and bool dtypes (exact up to 2^53).
    pub fn to_f64(&self) -> Result<Vec<f64>, DecodeError> {
        let (order, kind, size) = parse_dtype(&self.dtype)?;
        let big = order == '>';
        let n = self.len();
        if self.data.len() != n * size {
            return err(format!(
                "array {:?} of shape {:?} has {} bytes, expected {}",
                self.dtype,
                self.shape,
                self.data.len(),
                n * size
            ));
        }
        macro_rules! conv {
            ($t:ty) => {
                self.data
                    .chunks_exact(size)
                    .map(|c| {
                        let b = c.try_into().expect("chunk of the item size");
                        (if big { <$t>::from_be_bytes(b) } else { <$t>::from_le_bytes(b) }) as f64
                    })
                    .collect()
            };
        }
        Ok(match (kind, size) {
            ('f', 4) => conv!(f32),
            ('f', 8) => conv!(f64),
            ('i', 1) => conv!(i8),
            ('i', 2) => conv!(i16),
            ('i', 4) => conv!(i32),
            ('i', 8) => conv!(i64),
            ('u', 1) | ('b', 1) => self.data.iter().map(|&b| b as f64).collect(),
            ('u', 2) => conv!(u16),
            ('u', 4) => conv!(u32),
            ('u', 8) => conv!(u64),
            _ => return err(format!("unsupported dtype {:?} for numeric values", self.dtype)),
        })
    }

    /// The packed form: a map with bin keys, as `pack_array` writes it.
    pub fn to_value(&self) -> Value {
        Value::Map(vec![
            (Value::Binary(NDARRAY_KEY.to_vec()), Value::Boolean(true)),
            (Value::Binary(b"data".to_vec()), Value::Binary(self.data.clone())),
            (Value::Binary(b"dtype".to_vec()), Value::from(self.dtype.as_str())),
            (Value::Binary(b"shape".to_vec()), Value::Array(self.shape.iter().map(|&d| Value::from(d)).collect())),
        ])
    }

    /// Reads a packed array; `Ok(None)` when `v` is not one (no `__ndarray__` key). Keys are
    /// accepted as bin (what openpi writes) or str (what a `use_bin_type=False` packer writes).
    pub fn from_value(v: &Value) -> Result<Option<NdArray>, DecodeError> {
        let Some(map) = v.as_map() else { return Ok(None) };
        if get(map, NDARRAY_KEY).is_none() {
            return Ok(None);
        }
        let data = match get(map, b"data") {
            Some(Value::Binary(b)) => b.clone(),
            Some(other) => return err(format!("ndarray data is not bytes: {other}")),
            None => return err("ndarray without data"),
        };
        let dtype = match get(map, b"dtype") {
            Some(Value::String(s)) => s.as_str().map(str::to_string),
            Some(Value::Binary(b)) => String::from_utf8(b.clone()).ok(),
            _ => None,
        }
        .ok_or_else(|| DecodeError("ndarray without a dtype string".into()))?;
        let shape = match get(map, b"shape") {
            Some(Value::Array(dims)) => dims
                .iter()
                .map(|d| d.as_u64().and_then(|d| usize::try_from(d).ok()))
                .collect::<Option<Vec<usize>>>()
                .ok_or_else(|| DecodeError(format!("ndarray shape is not non-negative integers: {dims:?}")))?,
            _ => return err("ndarray without a shape array"),
        };
        let (_, kind, size) = parse_dtype(&dtype)?;
        if matches!(kind, 'O' | 'V' | 'c') {
            return err(format!("unsupported ndarray dtype {dtype:?}"));
        }
        let n = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
        match n.and_then(|n| n.checked_mul(size)) {
            Some(bytes) if bytes == data.len() => Ok(Some(NdArray { dtype, shape, data })),
            _ => err(format!("ndarray {dtype:?} of shape {shape:?} does not match its {} data bytes", data.len())),
        }
    }
}

/// `dtype.str` → (byte order, kind, item size).
fn parse_dtype(dtype: &str) -> Result<(char, char, usize), DecodeError> {
    let mut chars = dtype.chars();
    let (Some(order), Some(kind)) = (chars.next(), chars.next()) else {
        return err(format!("bad dtype {dtype:?}"));
    };
    let size: usize = chars.as_str().parse().map_err(|_| DecodeError(format!("bad dtype {dtype:?}")))?;
    if !matches!(order, '<' | '>' | '|' | '=') || size == 0 {
        return err(format!("bad dtype {dtype:?}"));
    }
    Ok((order, kind, size))
}

/// The value of a map entry whose key is `key` as bin or as str.
pub fn get<'a>(map: &'a [(Value, Value)], key: &[u8]) -> Option<&'a Value> {
    map.iter()
        .find(|(k, _)| match k {
            Value::Binary(b) => b == key,
            Value::String(s) => s.as_bytes() == key,
            _ => false,
        })
        .map(|(_, v)| v)
}

/// MessagePack bytes of a value (as `msgpack.packb`).
pub fn pack(v: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    rmpv::encode::write_value(&mut out, v).expect("writing MessagePack to a Vec cannot fail");
    out
}

/// One MessagePack value from `bytes`, which must hold exactly one.
pub fn unpack(bytes: &[u8]) -> Result<Value, DecodeError> {
    let mut rd = bytes;
    let v = rmpv::decode::read_value(&mut rd).map_err(|e| DecodeError(format!("not MessagePack: {e}")))?;
    if !rd.is_empty() {
        return err(format!("{} bytes after the MessagePack value", rd.len()));
    }
    Ok(v)
}

/// Elements of a large array kept in the JSON form (above: dtype, shape and byte count only).
const JSON_ARRAY_MAX: usize = 1024;

/// A JSON rendering of a decoded value, for the run manifest (the server's metadata): arrays
/// become `{"dtype", "shape", "values"}` (values omitted above 1024 elements), NumPy scalars their
/// value, bin a `{"bytes": n}` note, non-finite floats `null`, non-string keys their display.
pub fn to_json(v: &Value) -> serde_json::Value {
    use serde_json::Value as J;
    match v {
        Value::Nil => J::Null,
        Value::Boolean(b) => J::Bool(*b),
        Value::Integer(i) => i.as_i64().map(J::from).or_else(|| i.as_u64().map(J::from)).unwrap_or(J::Null),
        Value::F32(f) => serde_json::Number::from_f64(*f as f64).map_or(J::Null, J::Number),
        Value::F64(f) => serde_json::Number::from_f64(*f).map_or(J::Null, J::Number),
        Value::String(s) => J::String(String::from_utf8_lossy(s.as_bytes()).into_owned()),
        Value::Binary(b) => serde_json::json!({ "bytes": b.len() }),
        Value::Array(a) => J::Array(a.iter().map(to_json).collect()),
        Value::Ext(t, b) => serde_json::json!({ "ext": t, "bytes": b.len() }),
        Value::Map(m) => {
            if let Ok(Some(a)) = NdArray::from_value(v) {
                let mut o = serde_json::json!({ "dtype": a.dtype, "shape": a.shape });
                match a.to_f64() {
                    Ok(x) if x.len() <= JSON_ARRAY_MAX => {
                        o["values"] =
                            x.into_iter().map(|f| serde_json::Number::from_f64(f).map_or(J::Null, J::Number)).collect()
                    }
                    _ => o["bytes"] = J::from(a.data.len()),
                }
                return o;
            }
            if get(m, NPGENERIC_KEY).is_some() {
                return get(m, b"data").map_or(J::Null, to_json);
            }
            J::Object(
                m.iter()
                    .map(|(k, v)| {
                        let key = match k {
                            Value::String(s) => String::from_utf8_lossy(s.as_bytes()).into_owned(),
                            Value::Binary(b) => String::from_utf8_lossy(b).into_owned(),
                            other => other.to_string(),
                        };
                        (key, to_json(v))
                    })
                    .collect(),
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_array_round_trips_through_messagepack_bytes() {
        let a = NdArray::from_f32(&[2, 7], &(0..14).map(|i| i as f32 * 0.5 - 3.0).collect::<Vec<_>>());
        let back = NdArray::from_value(&unpack(&pack(&a.to_value())).unwrap()).unwrap().unwrap();
        assert_eq!(back, a);
        assert_eq!(back.to_f64().unwrap()[13], 3.5);
        let img = NdArray::from_u8(&[4, 4, 3], (0..48).collect());
        let back = NdArray::from_value(&unpack(&pack(&img.to_value())).unwrap()).unwrap().unwrap();
        assert_eq!(back, img);
        let s = NdArray::from_f64(&[8], &[1.0, -2.0, 3.25, 0.0, 1e-300, f64::MAX, -0.5, 7.0]);
        assert_eq!(
            NdArray::from_value(&unpack(&pack(&s.to_value())).unwrap()).unwrap().unwrap().to_f64().unwrap(),
            [1.0, -2.0, 3.25, 0.0, 1e-300, f64::MAX, -0.5, 7.0]
        );
    }

    /// The exact bytes `msgpack_numpy.packb(np.array([1.5, -2.0], dtype=np.float32))` gives
    /// (msgpack 1.2.4, openpi-client 0.1.2): bin keys (0xc4), str dtype (0xa3), array shape (0x91).
    #[test]
    fn bytes_match_what_python_writes() {
        let python: &[u8] = &[
            0x84, 0xc4, 0x0b, b'_', b'_', b'n', b'd', b'a', b'r', b'r', b'a', b'y', b'_', b'_', 0xc3, 0xc4, 0x04, b'd',
            b'a', b't', b'a', 0xc4, 0x08, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0x00, 0xc0, 0xc4, 0x05, b'd', b't', b'y',
            b'p', b'e', 0xa3, b'<', b'f', b'4', 0xc4, 0x05, b's', b'h', b'a', b'p', b'e', 0x91, 0x02,
        ];
        let a = NdArray::from_f32(&[2], &[1.5, -2.0]);
        assert_eq!(pack(&a.to_value()), python);
        assert_eq!(NdArray::from_value(&unpack(python).unwrap()).unwrap().unwrap(), a);
    }

    #[test]
    fn big_endian_and_integer_dtypes_decode() {
        let a = NdArray {
            dtype: ">f8".into(),
            shape: vec![2],
            data: [1.5f64.to_be_bytes(), (-4.0f64).to_be_bytes()].concat(),
        };
        assert_eq!(a.to_f64().unwrap(), [1.5, -4.0]);
        let i = NdArray {
            dtype: "<i4".into(),
            shape: vec![3],
            data: [-1i32, 0, 9].iter().flat_map(|v| v.to_le_bytes()).collect(),
        };
        assert_eq!(i.to_f64().unwrap(), [-1.0, 0.0, 9.0]);
        assert!(NdArray { dtype: "<f2".into(), shape: vec![1], data: vec![0, 0] }.to_f64().is_err());
    }

    #[test]
    fn malformed_arrays_are_errors_not_panics() {
        let mut v = NdArray::from_f32(&[3], &[1.0, 2.0, 3.0]).to_value();
        // shape says 4 elements, data holds 3
        if let Value::Map(m) = &mut v {
            m[3].1 = Value::Array(vec![Value::from(4)]);
        }
        assert!(NdArray::from_value(&v).unwrap_err().0.contains("does not match"));
        let huge = NdArray { dtype: "<f8".into(), shape: vec![usize::MAX, 2], data: vec![] }.to_value();
        assert!(NdArray::from_value(&huge).is_err());
        let bad = NdArray { dtype: "f".into(), shape: vec![0], data: vec![] }.to_value();
        assert!(NdArray::from_value(&bad).unwrap_err().0.contains("bad dtype"));
        let obj = NdArray { dtype: "|O8".into(), shape: vec![0], data: vec![] }.to_value();
        assert!(NdArray::from_value(&obj).is_err());
        assert!(unpack(&[0xc4, 0x10, 1, 2]).is_err()); // bin of 16 bytes, 2 present
        assert!(unpack(&[0x90, 0x90]).unwrap_err().0.contains("after"));
        assert_eq!(NdArray::from_value(&Value::from("x")).unwrap(), None);
    }

    #[test]
    fn metadata_becomes_json_for_the_manifest() {
        let v = Value::Map(vec![
            (Value::from("action_horizon"), Value::from(10)),
            (Value::from("norm"), NdArray::from_f32(&[2], &[0.5, 1.0]).to_value()),
            (
                Value::from("scalar"),
                Value::Map(vec![
                    (Value::Binary(NPGENERIC_KEY.to_vec()), Value::Boolean(true)),
                    (Value::Binary(b"data".to_vec()), Value::F64(2.5)),
                    (Value::Binary(b"dtype".to_vec()), Value::from("<f8")),
                ]),
            ),
            (Value::Binary(b"raw".to_vec()), Value::F64(f64::NAN)),
        ]);
        assert_eq!(
            to_json(&v),
            serde_json::json!({
                "action_horizon": 10,
                "norm": {"dtype": "<f4", "shape": [2], "values": [0.5, 1.0]},
                "scalar": 2.5,
                "raw": null,
            })
        );
    }
}
