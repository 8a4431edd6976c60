//! Named f32 and i32 tensors to and from safetensors files (datasets, bundles, fixtures);
//! reading checks each tensor's dtype and shape and names the file and tensor when wrong.
//! A float tensor stored as F16, or as I8 with an F16 scale per group of [`QUANT_GROUP`]
//! consecutive values (the last group shorter) in the tensor `<name>:scale` (the shipped
//! bundles' weights, to fit two avatars in the clone), or as an I8 difference from another
//! tensor ([`DELTA_OF`]), is read as f32: every stage computes in f32 from the widened
//! values.

use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors};

use crate::files::{WriteError, write_atomic};

/// Values per scale of an I8 tensor (`train/unica_train/bundle.py` writes them).
pub const QUANT_GROUP: usize = 32;

/// The name of an I8 tensor's scales.
pub fn scale_name(name: &str) -> String {
    format!("{name}:scale")
}

/// Tensors stored as an I8 difference from another (prefix, its base's prefix): the
/// one-pass student's from the 10-step UNet's array of the same name, its scales in
/// `<name>:delta` (`DELTA_OF` in `train/unica_train/bundle.py`).
pub const DELTA_OF: &[(&str, &str)] = &[("student.", "unet.")];

/// The name of an I8 difference's scales.
pub fn delta_name(name: &str) -> String {
    format!("{name}:delta")
}

/// The tensor that `name` is stored as a difference from, if any.
fn delta_base(name: &str) -> Option<String> {
    DELTA_OF.iter().find_map(|(prefix, base)| {
        name.strip_prefix(prefix)
            .map(|rest| format!("{base}{rest}"))
    })
}

/// A tensor to write: dtype, shape and little-endian bytes.
pub struct TensorData {
    dtype: Dtype,
    shape: Vec<usize>,
    data: Vec<u8>,
}

impl TensorData {
    pub fn f32(shape: &[usize], values: &[f32]) -> Self {
        assert_eq!(
            shape.iter().product::<usize>(),
            values.len(),
            "tensor shape and data disagree"
        );
        Self {
            dtype: Dtype::F32,
            shape: shape.to_vec(),
            data: bytemuck::cast_slice(values).to_vec(),
        }
    }

    pub fn i32(shape: &[usize], values: &[i32]) -> Self {
        assert_eq!(
            shape.iter().product::<usize>(),
            values.len(),
            "tensor shape and data disagree"
        );
        Self {
            dtype: Dtype::I32,
            shape: shape.to_vec(),
            data: bytemuck::cast_slice(values).to_vec(),
        }
    }
}

impl safetensors::View for &TensorData {
    fn dtype(&self) -> Dtype {
        self.dtype
    }
    fn shape(&self) -> &[usize] {
        &self.shape
    }
    fn data(&self) -> std::borrow::Cow<'_, [u8]> {
        (&self.data).into()
    }
    fn data_len(&self) -> usize {
        self.data.len()
    }
}

/// Writes the tensors atomically (same tensors, same bytes: the format sorts them).
pub fn write(path: &Path, tensors: &[(&str, TensorData)]) -> Result<(), WriteError> {
    let bytes =
        safetensors::serialize(tensors.iter().map(|(name, t)| (*name, t)), None).map_err(|e| {
            WriteError {
                path: path.to_path_buf(),
                source: std::io::Error::other(e),
            }
        })?;
    write_atomic(path, &bytes)
}

#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct TensorError {
    pub path: PathBuf,
    pub problem: String,
}

/// A safetensors file read into memory.
pub struct TensorFile {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl TensorFile {
    pub fn open(path: &Path) -> Result<Self, TensorError> {
        let bytes = std::fs::read(path).map_err(|e| TensorError {
            path: path.to_path_buf(),
            problem: e.to_string(),
        })?;
        Self::from_bytes(path, bytes)
    }

    /// The file read by the caller (`path` names it in errors).
    pub fn from_bytes(path: &Path, bytes: Vec<u8>) -> Result<Self, TensorError> {
        let file = Self {
            path: path.to_path_buf(),
            bytes,
        };
        file.parsed()?;
        Ok(file)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether the file holds a tensor called `name`.
    pub fn contains(&self, name: &str) -> bool {
        self.parsed().is_ok_and(|t| t.tensor(name).is_ok())
    }

    fn fail(&self, problem: String) -> TensorError {
        TensorError {
            path: self.path.clone(),
            problem,
        }
    }

    fn parsed(&self) -> Result<SafeTensors<'_>, TensorError> {
        SafeTensors::deserialize(&self.bytes)
            .map_err(|e| self.fail(format!("not a safetensors file: {e}")))
    }

    /// A tensor's values and shape; `shape` gives the expected size of each dimension
    /// (`None` for any).
    fn read<T: bytemuck::Pod>(
        &self,
        name: &str,
        dtype: Dtype,
        shape: &[Option<usize>],
    ) -> Result<(Vec<T>, Vec<usize>), TensorError> {
        self.read_any(name, &[dtype], shape)
            .map(|(bytes, _, found)| (bytemuck::pod_collect_to_vec(&bytes), found))
    }

    /// A tensor's raw bytes, its dtype (one of `dtypes`) and its shape.
    fn read_any(
        &self,
        name: &str,
        dtypes: &[Dtype],
        shape: &[Option<usize>],
    ) -> Result<(Vec<u8>, Dtype, Vec<usize>), TensorError> {
        let parsed = self.parsed()?;
        let view = parsed
            .tensor(name)
            .map_err(|_| self.fail(format!("tensor '{name}' is missing")))?;
        let dtype = dtypes[0];
        if !dtypes.contains(&view.dtype()) {
            return Err(self.fail(format!(
                "tensor '{name}' is {:?}, expected {dtype:?}",
                view.dtype()
            )));
        }
        let found = view.shape();
        let fits = found.len() == shape.len()
            && found
                .iter()
                .zip(shape)
                .all(|(f, s)| s.is_none_or(|s| s == *f));
        if !fits {
            let want: Vec<String> = shape
                .iter()
                .map(|s| s.map_or("*".into(), |s| s.to_string()))
                .collect();
            return Err(self.fail(format!(
                "tensor '{name}' has shape {found:?}, expected [{}]",
                want.join(", ")
            )));
        }
        Ok((view.data().to_vec(), view.dtype(), found.to_vec()))
    }

    /// An F32 tensor, or an F16 one widened to f32, or an I8 one times its scales (added
    /// to its base where it is stored as a difference, [`DELTA_OF`]).
    pub fn f32(
        &self,
        name: &str,
        shape: &[Option<usize>],
    ) -> Result<(Vec<f32>, Vec<usize>), TensorError> {
        let (bytes, dtype, found) =
            self.read_any(name, &[Dtype::F32, Dtype::F16, Dtype::I8], shape)?;
        let values = match dtype {
            Dtype::F16 => widen(&bytes),
            Dtype::I8 => {
                let groups = bytes.len().div_ceil(QUANT_GROUP);
                let delta = self.contains(&delta_name(name));
                let scales_of = if delta {
                    delta_name(name)
                } else {
                    scale_name(name)
                };
                let scales = widen(&self.read_any(&scales_of, &[Dtype::F16], &[Some(groups)])?.0);
                let mut values: Vec<f32> = bytes
                    .iter()
                    .enumerate()
                    .map(|(i, &q)| f32::from(q as i8) * scales[i / QUANT_GROUP])
                    .collect();
                if delta {
                    let base = delta_base(name).ok_or_else(|| {
                        self.fail(format!(
                            "tensor '{name}' is stored as a difference from nothing"
                        ))
                    })?;
                    let wanted: Vec<_> = found.iter().map(|&n| Some(n)).collect();
                    let (base, _) = self.f32(&base, &wanted)?;
                    values.iter_mut().zip(base).for_each(|(v, b)| *v += b);
                }
                values
            }
            _ => bytemuck::pod_collect_to_vec(&bytes),
        };
        Ok((values, found))
    }

    pub fn i32(
        &self,
        name: &str,
        shape: &[Option<usize>],
    ) -> Result<(Vec<i32>, Vec<usize>), TensorError> {
        self.read(name, Dtype::I32, shape)
    }
}

/// Little-endian F16 bytes widened to f32 (exactly).
fn widen(bytes: &[u8]) -> Vec<f32> {
    bytemuck::pod_collect_to_vec::<u8, half::f16>(bytes)
        .into_iter()
        .map(f32::from)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_named_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.safetensors");
        write(
            &path,
            &[
                ("a", TensorData::f32(&[2, 2], &[1.0, 2.0, 3.0, 4.0])),
                ("b", TensorData::i32(&[3], &[7, 8, 9])),
            ],
        )
        .unwrap();
        let first = std::fs::read(&path).unwrap();
        write(
            &path,
            &[
                ("b", TensorData::i32(&[3], &[7, 8, 9])),
                ("a", TensorData::f32(&[2, 2], &[1.0, 2.0, 3.0, 4.0])),
            ],
        )
        .unwrap();
        assert_eq!(
            std::fs::read(&path).unwrap(),
            first,
            "same tensors, same bytes"
        );
        let file = TensorFile::open(&path).unwrap();
        assert_eq!(
            file.f32("a", &[Some(2), None]).unwrap(),
            (vec![1.0, 2.0, 3.0, 4.0], vec![2, 2])
        );
        assert_eq!(file.i32("b", &[Some(3)]).unwrap().0, vec![7, 8, 9]);
        // F16 is widened exactly: 1, -2, 0.5 and 65504 (the largest half) are all
        // representable, and 0x3555 is the half nearest 1/3 (0.333251953125).
        let halves: [u16; 5] = [0x3c00, 0xc000, 0x3800, 0x7bff, 0x3555];
        let h = TensorData {
            dtype: Dtype::F16,
            shape: vec![5],
            data: bytemuck::cast_slice(&halves).to_vec(),
        };
        let half_path = dir.path().join("h.safetensors");
        write(&half_path, &[("h", h)]).unwrap();
        let widened = TensorFile::open(&half_path)
            .unwrap()
            .f32("h", &[Some(5)])
            .unwrap()
            .0;
        assert_eq!(widened, vec![1.0, -2.0, 0.5, 65504.0, 0.333_251_95]);
        let e = file.f32("b", &[Some(3)]).unwrap_err().to_string();
        assert!(
            e.contains("t.safetensors") && e.contains("'b' is I32"),
            "{e}"
        );
        let e = file.f32("a", &[Some(3), Some(2)]).unwrap_err().to_string();
        assert!(e.contains("shape [2, 2], expected [3, 2]"), "{e}");
        assert!(
            file.f32("c", &[])
                .unwrap_err()
                .to_string()
                .contains("'c' is missing")
        );
        // I8 times the F16 scale of its group of 32: group 0 has scale 0.5, group 1
        // scale 2, so q = 127, -128, 3 read 63.5, -64, 1.5 and then 254, -256, 6.
        let q: Vec<i8> = (0..64).map(|i| [127i8, -128, 3][i % 3]).collect();
        let i8_tensor = TensorData {
            dtype: Dtype::I8,
            shape: vec![2, 32],
            data: bytemuck::cast_slice(&q).to_vec(),
        };
        let scales: [u16; 2] = [0x3800, 0x4000];
        let scale = TensorData {
            dtype: Dtype::F16,
            shape: vec![2],
            data: bytemuck::cast_slice(&scales).to_vec(),
        };
        let q_path = dir.path().join("q.safetensors");
        write(&q_path, &[("w", i8_tensor), ("w:scale", scale)]).unwrap();
        let (values, shape) = TensorFile::open(&q_path)
            .unwrap()
            .f32("w", &[Some(2), None])
            .unwrap();
        assert_eq!(shape, vec![2, 32]);
        let expected: Vec<f32> = (0..64)
            .map(|i| [127.0, -128.0, 3.0][i % 3] * if i < 32 { 0.5 } else { 2.0 })
            .collect();
        assert_eq!(values, expected);
        // 33 values: a second group of one.
        let short = TensorData {
            dtype: Dtype::I8,
            shape: vec![33],
            data: vec![2; 33],
        };
        let scale = TensorData {
            dtype: Dtype::F16,
            shape: vec![2],
            data: bytemuck::cast_slice(&scales).to_vec(),
        };
        write(&q_path, &[("w", short), ("w:scale", scale)]).unwrap();
        let (values, _) = TensorFile::open(&q_path)
            .unwrap()
            .f32("w", &[Some(33)])
            .unwrap();
        assert_eq!((values[31], values[32]), (1.0, 4.0));
        let lone = TensorData {
            dtype: Dtype::I8,
            shape: vec![32],
            data: vec![1; 32],
        };
        write(&q_path, &[("w", lone)]).unwrap();
        let e = TensorFile::open(&q_path)
            .unwrap()
            .f32("w", &[None])
            .unwrap_err()
            .to_string();
        assert!(e.contains("tensor 'w:scale' is missing"), "{e}");
        std::fs::write(&path, b"junk").unwrap();
        assert!(
            TensorFile::open(&path)
                .err()
                .unwrap()
                .to_string()
                .contains("not a safetensors file")
        );
    }

    #[test]
    fn a_difference_is_added_to_its_base() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.safetensors");
        let int8 = |q: &[i8]| TensorData {
            dtype: Dtype::I8,
            shape: vec![2, 16],
            data: bytemuck::cast_slice(q).to_vec(),
        };
        // One group of 32; 0x3800 = 0.5 and 0x3400 = 0.25.
        let half = |h: u16| TensorData {
            dtype: Dtype::F16,
            shape: vec![1],
            data: bytemuck::cast_slice(&[h]).to_vec(),
        };
        let base: Vec<i8> = vec![2; 32];
        let diff: Vec<i8> = (0..32).map(|i| if i % 2 == 0 { 1 } else { -3 }).collect();
        write(
            &path,
            &[
                ("unet.w", int8(&base)),
                ("unet.w:scale", half(0x3800)),
                ("student.w", int8(&diff)),
                ("student.w:delta", half(0x3400)),
            ],
        )
        .unwrap();
        let file = TensorFile::open(&path).unwrap();
        let (values, shape) = file.f32("student.w", &[Some(2), Some(16)]).unwrap();
        assert_eq!(shape, vec![2, 16]);
        let expected: Vec<f32> = (0..32)
            .map(|i| if i % 2 == 0 { 1.25 } else { 0.25 })
            .collect();
        assert_eq!(values, expected);
        // Without its base, the error names the missing tensor.
        write(
            &path,
            &[
                ("student.w", int8(&diff)),
                ("student.w:delta", half(0x3400)),
            ],
        )
        .unwrap();
        let e = TensorFile::open(&path)
            .unwrap()
            .f32("student.w", &[None, None])
            .unwrap_err()
            .to_string();
        assert!(e.contains("'unet.w' is missing"), "{e}");
    }
}
