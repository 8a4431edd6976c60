//! Point serialisation for the refiner (PTv3): positions in the unit cube quantised to
//! 1024 cells per axis and ordered along a z-order or Hilbert curve, or their transposes
//! (x and y swapped). The same arithmetic as train/unica_train/refiner/model.py. This is
//! the host reference of the orders [`super::frame`] makes on the GPU; the CPU appearance
//! path and the refiner's parity tests upload it ([`HostOrders::upload`]).

use glam::Vec3;

use crate::gpu::indices::inverse;
use crate::gpu::{GpuContext, GpuError, Indices, Permutation};

const BITS: u32 = 10;

/// The four orders, in the refiner's block order (block i uses `ORDERS[i % 4]`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Curve {
    Z,
    ZTransposed,
    Hilbert,
    HilbertTransposed,
}

pub const ORDERS: [Curve; 4] = [
    Curve::Z,
    Curve::ZTransposed,
    Curve::Hilbert,
    Curve::HilbertTransposed,
];

/// The cell of a unit-cube position.
pub fn quantise(p: Vec3) -> [u32; 3] {
    let cells = (1u32 << BITS) as f32;
    p.to_array()
        .map(|v| (v * cells).floor().clamp(0.0, cells - 1.0) as u32)
}

/// Bits interleaved from the most significant: x₉ y₉ z₉ x₈ …
fn interleave([x, y, z]: [u32; 3]) -> u64 {
    let mut code = 0u64;
    for b in (0..BITS).rev() {
        for axis in [x, y, z] {
            code = (code << 1) | u64::from((axis >> b) & 1);
        }
    }
    code
}

pub fn z_order(cell: [u32; 3]) -> u64 {
    interleave(cell)
}

/// The Hilbert index of a cell (Skilling's transpose algorithm, then interleaved).
pub fn hilbert(cell: [u32; 3]) -> u64 {
    let mut x = cell;
    let mut q = 1u32 << (BITS - 1);
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1;
    }
    for i in 1..3 {
        x[i] ^= x[i - 1];
    }
    let mut t = 0;
    let mut q = 1u32 << (BITS - 1);
    while q > 1 {
        if x[2] & q != 0 {
            t ^= q - 1;
        }
        q >>= 1;
    }
    interleave(x.map(|v| v ^ t))
}

/// The order (a permutation) of `points` along `curve`; ties keep index order.
pub fn serialise(points: &[Vec3], curve: Curve) -> Vec<u32> {
    let codes: Vec<u64> = points
        .iter()
        .map(|&p| {
            let [x, y, z] = quantise(p);
            match curve {
                Curve::Z => z_order([x, y, z]),
                Curve::ZTransposed => z_order([y, x, z]),
                Curve::Hilbert => hilbert([x, y, z]),
                Curve::HilbertTransposed => hilbert([y, x, z]),
            }
        })
        .collect();
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    order.sort_by_key(|&i| codes[i as usize]);
    order
}

/// The mean position of each run of `stride` points along `order`, summed in order.
pub fn pooled_positions(points: &[Vec3], order: &[u32], stride: usize) -> Vec<Vec3> {
    order
        .chunks(stride)
        .map(|run| {
            let sum = run
                .iter()
                .fold(Vec3::ZERO, |acc, &i| acc + points[i as usize]);
            sum / run.len() as f32
        })
        .collect()
}

/// Each point's pooled group: its rank along `order` divided by `stride`.
pub fn groups(order: &[u32], stride: usize) -> Vec<u32> {
    inverse(order)
        .into_iter()
        .map(|rank| rank / stride as u32)
        .collect()
}

/// The refiner's orders of one frame's points, on the host: the four curves of the points
/// and of their pooled points (runs of `stride` along the first curve), and each point's
/// pooled group.
pub struct HostOrders {
    pub fine: Vec<Vec<u32>>,
    pub coarse: Vec<Vec<u32>>,
    pub groups: Vec<u32>,
}

/// The refiner's orders of one frame's points on the GPU, as the refiner reads them.
pub struct SerialOrders {
    pub fine: Vec<Permutation>,
    pub coarse: Vec<Permutation>,
    pub groups: Indices,
}

/// The orders of points at `unit` (normalised, root at 0.5) pooled in runs of `stride`.
pub fn host_orders(unit: &[Vec3], stride: usize) -> HostOrders {
    let fine: Vec<Vec<u32>> = ORDERS.iter().map(|&c| serialise(unit, c)).collect();
    let coarse_unit = pooled_positions(unit, &fine[0], stride);
    HostOrders {
        coarse: ORDERS.iter().map(|&c| serialise(&coarse_unit, c)).collect(),
        groups: groups(&fine[0], stride),
        fine,
    }
}

impl HostOrders {
    pub fn upload(&self, gpu: &GpuContext) -> Result<SerialOrders, GpuError> {
        let permutations = |orders: &[Vec<u32>]| {
            orders
                .iter()
                .map(|o| Permutation::upload(gpu, "refiner.order", o))
                .collect::<Result<Vec<_>, _>>()
        };
        Ok(SerialOrders {
            fine: permutations(&self.fine)?,
            coarse: permutations(&self.coarse)?,
            groups: Indices::upload(gpu, "refiner.groups", &self.groups)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_order_interleaves_x_then_y_then_z() {
        assert_eq!(z_order([1, 0, 0]), 4);
        assert_eq!(z_order([0, 1, 0]), 2);
        assert_eq!(z_order([0, 0, 1]), 1);
        assert_eq!(z_order([2, 0, 0]), 32);
        assert_eq!(z_order([1023, 1023, 1023]), (1 << 30) - 1);
    }

    #[test]
    fn the_hilbert_curve_walks_its_first_octant_block_cell_by_cell() {
        // The first 64 indices of the curve fill the 4×4×4 block at the origin, and
        // consecutive indices are face neighbours.
        let mut cells: Vec<([u32; 3], u64)> = (0..64u32)
            .map(|i| [i / 16, (i / 4) % 4, i % 4])
            .map(|c| (c, hilbert(c)))
            .collect();
        cells.sort_by_key(|&(_, code)| code);
        let codes: Vec<u64> = cells.iter().map(|&(_, code)| code).collect();
        assert_eq!(codes, (0..64).collect::<Vec<u64>>());
        for pair in cells.windows(2) {
            let step: u32 = (0..3).map(|k| pair[0].0[k].abs_diff(pair[1].0[k])).sum();
            assert_eq!(step, 1, "{:?} -> {:?}", pair[0].0, pair[1].0);
        }
    }

    #[test]
    fn orders_are_permutations_and_ties_keep_index_order() {
        let points = [
            Vec3::new(0.9, 0.1, 0.1),
            Vec3::new(0.1, 0.1, 0.1),
            Vec3::new(0.1, 0.1, 0.1),
            Vec3::new(0.1, 0.9, 0.1),
        ];
        for curve in ORDERS {
            let order = serialise(&points, curve);
            let mut sorted = order.clone();
            sorted.sort();
            assert_eq!(sorted, [0, 1, 2, 3]);
            let a = order.iter().position(|&i| i == 1).unwrap();
            let b = order.iter().position(|&i| i == 2).unwrap();
            assert_eq!(b, a + 1, "{curve:?}: equal cells stay in index order");
        }
        // Transposing swaps which of x and y is the most significant.
        assert_eq!(serialise(&points, Curve::Z), [1, 2, 3, 0]);
        assert_eq!(serialise(&points, Curve::ZTransposed), [1, 2, 0, 3]);
    }

    #[test]
    fn pooling_averages_runs_along_the_order() {
        let points = [Vec3::X, Vec3::Y, Vec3::Z, Vec3::ONE, Vec3::ZERO];
        let order = [4, 0, 1, 2, 3];
        let pooled = pooled_positions(&points, &order, 2);
        assert_eq!(
            pooled,
            [Vec3::X * 0.5, (Vec3::Y + Vec3::Z) * 0.5, Vec3::ONE]
        );
        assert_eq!(groups(&order, 2), [0, 1, 1, 2, 0]);
    }
}
