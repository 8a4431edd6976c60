//! Row indices in a u32 storage buffer, and permutations of rows (an order and its
//! inverse): what one stage writes and another reads by row, such as the serialisation
//! orders the splat stage writes and the refiner gathers by.

use super::{GpuContext, GpuError};

/// Row indices in a u32 storage buffer; rewritable in place (e.g. the action ids of a
/// captured plan).
#[derive(Clone, Debug)]
pub struct Indices {
    pub(crate) buffer: wgpu::Buffer,
    pub(crate) len: usize,
}

impl Indices {
    /// `values` uploaded into a new storage buffer.
    pub fn upload(gpu: &GpuContext, label: &str, values: &[u32]) -> Result<Self, GpuError> {
        let buffer = gpu.storage_buffer_init(
            label,
            bytemuck::cast_slice(values),
            wgpu::BufferUsages::empty(),
        )?;
        Ok(Self {
            buffer,
            len: values.len(),
        })
    }

    /// `len` indices for a kernel to write (a buffer of at least 4 bytes).
    pub fn storage(gpu: &GpuContext, label: &str, len: usize) -> Result<Self, GpuError> {
        let bytes = 4 * len.max(1) as u64;
        let buffer = gpu.storage_buffer(label, bytes, wgpu::BufferUsages::empty())?;
        Ok(Self { buffer, len })
    }

    /// Indices already in a u32 storage buffer (e.g. written by another stage's kernel).
    pub fn from_buffer(buffer: &wgpu::Buffer, len: usize) -> Self {
        Self {
            buffer: buffer.clone(),
            len,
        }
    }

    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Overwrites the indices (same count) before the next submission that reads them.
    pub fn write(&self, gpu: &GpuContext, values: &[u32]) {
        assert_eq!(values.len(), self.len, "index count");
        gpu.queue
            .write_buffer(&self.buffer, 0, bytemuck::cast_slice(values));
    }
}

/// A permutation of rows: `sort[i]` is the row at place i of the order, `unsort[row]` the
/// place of `row`, so gathering by `sort` and then by `unsort` gives the rows back.
#[derive(Clone, Debug)]
pub struct Permutation {
    pub sort: Indices,
    pub unsort: Indices,
}

impl Permutation {
    /// `order` (a permutation of 0..n) and its inverse, uploaded.
    pub fn upload(gpu: &GpuContext, label: &str, order: &[u32]) -> Result<Self, GpuError> {
        Ok(Self {
            sort: Indices::upload(gpu, label, order)?,
            unsort: Indices::upload(gpu, label, &inverse(order))?,
        })
    }

    /// A permutation of `len` rows for a kernel to write.
    pub fn storage(gpu: &GpuContext, label: &str, len: usize) -> Result<Self, GpuError> {
        Ok(Self {
            sort: Indices::storage(gpu, label, len)?,
            unsort: Indices::storage(gpu, label, len)?,
        })
    }
}

/// The inverse of a permutation of 0..n: `inverse(order)[order[i]] = i`.
pub fn inverse(order: &[u32]) -> Vec<u32> {
    places(order, order.len(), u32::MAX)
}

/// Each of 0..len's place in `order` (distinct values below `len`), or `missing` where
/// `order` does not hold it: `places(order, len, missing)[order[i]] = i`.
pub fn places(order: &[u32], len: usize, missing: u32) -> Vec<u32> {
    let mut out = vec![missing; len];
    for (i, &p) in order.iter().enumerate() {
        out[p as usize] = i as u32;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_inverse_undoes_the_order() {
        let order = [2, 0, 3, 1];
        let unsort = inverse(&order);
        assert_eq!(unsort, [1, 3, 0, 2]);
        for (i, &p) in order.iter().enumerate() {
            assert_eq!(unsort[p as usize] as usize, i);
        }
        assert_eq!(places(&[3, 0], 5, 9), [1, 9, 9, 0, 9]);
    }
}
