//! Python `torch.save` files of plain tensors (a state dict), read without Python: OpenVLA-OFT
//! ships its action head and proprio projector as `action_head--*.pt` / `proprio_projector--*.pt`.
//!
//! tch cannot read them: its `.pt` loaders are TorchScript's (`torch::jit::load`, which wants
//! `constants.pkl`) and the mobile parameter loader (`_load_parameters`, which wants its own dict
//! layout); both fail on a `torch.save(OrderedDict)` (checked on libtorch 2.11). The format is
//! small, so it is read here: a zip archive (entries stored, not compressed) with
//! `<name>/data.pkl`, a pickle (protocol 2) of the dict whose tensors are
//! `torch._utils._rebuild_tensor_v2(storage, offset, size, stride, ...)` calls on persistent ids
//! `('storage', torch.<Kind>Storage, key, location, numel)`, and each storage's bytes in
//! `<name>/data/<key>` (little-endian). The pickle machine below runs only the opcodes and
//! callables such a file uses, and refuses anything else (no arbitrary Python objects).

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;
use tch::{Kind, Tensor};

#[derive(Debug, Clone)]
enum V {
    /// None, booleans, floats: read, never used
    Scalar,
    Int(i64),
    Str(String),
    Tuple(Vec<V>),
    List(Vec<V>),
    Dict(Vec<(V, V)>),
    Global(String, String),
    Storage {
        kind: Kind,
        key: String,
    },
    Tensor(TensorRef),
    Mark,
}

#[derive(Debug, Clone)]
struct TensorRef {
    kind: Kind,
    key: String,
    offset: i64,
    size: Vec<i64>,
    stride: Vec<i64>,
}

fn storage_kind(name: &str) -> Option<Kind> {
    Some(match name {
        "FloatStorage" => Kind::Float,
        "DoubleStorage" => Kind::Double,
        "HalfStorage" => Kind::Half,
        "BFloat16Storage" => Kind::BFloat16,
        "LongStorage" => Kind::Int64,
        "IntStorage" => Kind::Int,
        "ShortStorage" => Kind::Int16,
        "CharStorage" => Kind::Int8,
        "ByteStorage" => Kind::Uint8,
        "BoolStorage" => Kind::Bool,
        _ => return None,
    })
}

fn ints(v: &V, what: &str) -> Result<Vec<i64>, String> {
    match v {
        V::Tuple(items) => items
            .iter()
            .map(|x| match x {
                V::Int(i) => Ok(*i),
                _ => Err(format!("{what}: not an integer")),
            })
            .collect(),
        _ => Err(format!("{what}: not a tuple")),
    }
}

struct Machine<'a> {
    data: &'a [u8],
    pos: usize,
    stack: Vec<V>,
    memo: HashMap<u32, V>,
}

impl Machine<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len()).ok_or("truncated pickle")?;
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().unwrap()))
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn line(&mut self) -> Result<String, String> {
        let rest = &self.data[self.pos..];
        let n = rest.iter().position(|&c| c == b'\n').ok_or("unterminated GLOBAL")?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.pos += n + 1;
        Ok(s)
    }
    fn pop(&mut self) -> Result<V, String> {
        self.stack.pop().ok_or_else(|| "pickle stack underflow".to_string())
    }
    fn pop_mark(&mut self) -> Result<Vec<V>, String> {
        let m = self.stack.iter().rposition(|v| matches!(v, V::Mark)).ok_or("MARK missing")?;
        let items = self.stack.split_off(m + 1);
        self.stack.pop();
        Ok(items)
    }
    fn top(&mut self) -> Result<&mut V, String> {
        self.stack.last_mut().ok_or_else(|| "pickle stack underflow".to_string())
    }
    fn set_items(&mut self, items: Vec<V>) -> Result<(), String> {
        if !items.len().is_multiple_of(2) {
            return Err("SETITEMS with an odd number of values".into());
        }
        let V::Dict(d) = self.top()? else { return Err("SETITEMS on a non-dict".into()) };
        let mut it = items.into_iter();
        while let (Some(k), Some(v)) = (it.next(), it.next()) {
            d.push((k, v));
        }
        Ok(())
    }

    fn reduce(&mut self, callable: V, args: V) -> Result<V, String> {
        let V::Global(module, name) = callable else { return Err("REDUCE of a non-global".into()) };
        let V::Tuple(args) = args else { return Err("REDUCE without an argument tuple".into()) };
        match (module.as_str(), name.as_str()) {
            ("collections", "OrderedDict") if args.is_empty() => Ok(V::Dict(Vec::new())),
            ("torch._utils", "_rebuild_tensor_v2") if args.len() >= 4 => {
                let V::Storage { kind, key } = &args[0] else {
                    return Err("_rebuild_tensor_v2 without a storage".into());
                };
                let V::Int(offset) = args[1] else { return Err("_rebuild_tensor_v2: offset".into()) };
                let size = ints(&args[2], "tensor size")?;
                let stride = ints(&args[3], "tensor stride")?;
                if size.len() != stride.len() {
                    return Err("tensor size and stride differ in length".into());
                }
                Ok(V::Tensor(TensorRef { kind: *kind, key: key.clone(), offset, size, stride }))
            }
            _ => Err(format!("unsupported object {module}.{name} (only tensors in (Ordered)dicts are read)")),
        }
    }

    fn run(&mut self) -> Result<V, String> {
        loop {
            let op = self.u8()?;
            match op {
                0x80 => {
                    self.u8()?; // PROTO
                }
                0x95 => {
                    self.take(8)?; // FRAME
                }
                b'.' => return self.pop(),
                b'(' => self.stack.push(V::Mark),
                b'N' => self.stack.push(V::Scalar),
                0x88 | 0x89 => self.stack.push(V::Scalar),
                b'K' => {
                    let v = self.u8()?;
                    self.stack.push(V::Int(i64::from(v)))
                }
                b'M' => {
                    let v = self.u16()?;
                    self.stack.push(V::Int(i64::from(v)))
                }
                b'J' => {
                    let v = self.u32()? as i32;
                    self.stack.push(V::Int(i64::from(v)))
                }
                0x8a => {
                    // LONG1: little-endian two's complement of n bytes
                    let n = self.u8()? as usize;
                    let b = self.take(n)?;
                    if n > 8 {
                        return Err("integer wider than 64 bits".into());
                    }
                    let mut buf = if b.last().is_some_and(|&x| x & 0x80 != 0) { [0xff; 8] } else { [0; 8] };
                    buf[..n].copy_from_slice(b);
                    self.stack.push(V::Int(i64::from_le_bytes(buf)))
                }
                b'G' => {
                    self.take(8)?;
                    self.stack.push(V::Scalar)
                }
                b'X' => {
                    let n = self.u32()? as usize;
                    let s = String::from_utf8_lossy(self.take(n)?).into_owned();
                    self.stack.push(V::Str(s))
                }
                0x8c => {
                    let n = self.u8()? as usize;
                    let s = String::from_utf8_lossy(self.take(n)?).into_owned();
                    self.stack.push(V::Str(s))
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    self.stack.push(V::Global(module, name))
                }
                b')' => self.stack.push(V::Tuple(Vec::new())),
                b't' => {
                    let items = self.pop_mark()?;
                    self.stack.push(V::Tuple(items))
                }
                0x85..=0x87 => {
                    let n = usize::from(op - 0x84);
                    if self.stack.len() < n {
                        return Err("pickle stack underflow".into());
                    }
                    let items = self.stack.split_off(self.stack.len() - n);
                    self.stack.push(V::Tuple(items))
                }
                b'}' => self.stack.push(V::Dict(Vec::new())),
                b']' => self.stack.push(V::List(Vec::new())),
                b's' => {
                    let v = self.pop()?;
                    let k = self.pop()?;
                    self.set_items(vec![k, v])?
                }
                b'u' => {
                    let items = self.pop_mark()?;
                    self.set_items(items)?
                }
                b'a' => {
                    let v = self.pop()?;
                    let V::List(l) = self.top()? else { return Err("APPEND on a non-list".into()) };
                    l.push(v)
                }
                b'e' => {
                    let items = self.pop_mark()?;
                    let V::List(l) = self.top()? else { return Err("APPENDS on a non-list".into()) };
                    l.extend(items)
                }
                b'q' => {
                    let i = u32::from(self.u8()?);
                    let v = self.top()?.clone();
                    self.memo.insert(i, v);
                }
                b'r' => {
                    let i = self.u32()?;
                    let v = self.top()?.clone();
                    self.memo.insert(i, v);
                }
                0x94 => {
                    let i = self.memo.len() as u32;
                    let v = self.top()?.clone();
                    self.memo.insert(i, v);
                }
                b'h' | b'j' => {
                    let i = if op == b'h' { u32::from(self.u8()?) } else { self.u32()? };
                    let v = self.memo.get(&i).cloned().ok_or_else(|| format!("memo {i} missing"))?;
                    self.stack.push(v)
                }
                b'R' => {
                    let args = self.pop()?;
                    let callable = self.pop()?;
                    let v = self.reduce(callable, args)?;
                    self.stack.push(v)
                }
                b'Q' => {
                    // BINPERSID: ('storage', torch.<Kind>Storage, key, location, numel)
                    let pid = self.pop()?;
                    let V::Tuple(t) = pid else { return Err("persistent id is not a tuple".into()) };
                    match t.as_slice() {
                        [V::Str(tag), V::Global(m, name), V::Str(key), ..] if tag == "storage" && m == "torch" => {
                            let kind = storage_kind(name).ok_or_else(|| format!("unsupported storage torch.{name}"))?;
                            self.stack.push(V::Storage { kind, key: key.clone() })
                        }
                        _ => return Err("persistent id is not a tensor storage".into()),
                    }
                }
                b'b' => {
                    // BUILD: the state dict's `_metadata` attribute (module versions), not needed
                    self.pop()?;
                }
                _ => return Err(format!("unsupported pickle opcode 0x{op:02x} at byte {}", self.pos - 1)),
            }
        }
    }
}

/// The tensors of a `torch.save`d dict of tensors, in the file's order, as contiguous CPU
/// tensors of their saved dtype.
pub fn read_state_dict(path: &Path) -> Result<Vec<(String, Tensor)>, String> {
    let fail = |e: String| format!("{}: {e}", path.display());
    let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
    let mut zip = zip::ZipArchive::new(file)
        .map_err(|e| fail(format!("not a torch.save zip archive ({e}); legacy (pre-1.6) .pt files are not read")))?;
    let pkl = zip
        .file_names()
        .find(|n| n.ends_with("/data.pkl") && n.matches('/').count() == 1)
        .map(str::to_string)
        .ok_or_else(|| fail("no <name>/data.pkl: not a torch.save file".into()))?;
    let prefix = pkl.trim_end_matches("data.pkl").to_string();
    let read = |zip: &mut zip::ZipArchive<std::fs::File>, name: &str| -> Result<Vec<u8>, String> {
        let mut entry = zip.by_name(name).map_err(|e| fail(format!("{name}: {e}")))?;
        let mut buf = Vec::with_capacity(entry.size() as usize);
        entry.read_to_end(&mut buf).map_err(|e| fail(format!("{name}: {e}")))?;
        Ok(buf)
    };
    if let Ok(order) = read(&mut zip, &format!("{prefix}byteorder"))
        && order != b"little"
    {
        return Err(fail(format!(
            "byteorder {:?}: only little-endian files are read",
            String::from_utf8_lossy(&order)
        )));
    }
    let data = read(&mut zip, &pkl)?;
    let mut m = Machine { data: &data, pos: 0, stack: Vec::new(), memo: HashMap::new() };
    let root = m.run().map_err(|e| fail(format!("data.pkl: {e}")))?;
    let V::Dict(items) = root else { return Err(fail("data.pkl is not a dict of tensors".into())) };
    let mut storages: HashMap<String, Vec<u8>> = HashMap::new();
    let mut out = Vec::with_capacity(items.len());
    for (k, v) in items {
        let (V::Str(name), V::Tensor(t)) = (k, v) else {
            return Err(fail("data.pkl: a dict entry is not (string, tensor)".into()));
        };
        if !storages.contains_key(&t.key) {
            let bytes = read(&mut zip, &format!("{prefix}data/{}", t.key))?;
            storages.insert(t.key.clone(), bytes);
        }
        let bytes = &storages[&t.key];
        let elem = t.kind.elt_size_in_bytes();
        let numel = (bytes.len() / elem) as i64;
        // the furthest element the view reaches must lie in the storage
        let reach = t.offset + t.size.iter().zip(&t.stride).map(|(s, st)| (s - 1).max(0) * st).sum::<i64>();
        if !t.size.contains(&0) && (t.offset < 0 || reach >= numel) {
            return Err(fail(format!("{name}: the view runs past its storage")));
        }
        let storage = Tensor::from_data_size(bytes, &[numel], t.kind);
        let tensor = storage.as_strided(&t.size, &t.stride, t.offset).contiguous();
        out.push((name, tensor));
    }
    Ok(out)
}
