use super::*;

#[test]
fn the_projection_into_images_equals_the_linear_layer_then_the_permute_bit_for_bit() {
    // The attention layers' output projection put back into NCHW images with their
    // residual (spatial: with an action-table row per sample; temporal: 3 frames per
    // sequence) in one dispatch on CPU drivers must equal linear then add_permuted(_bias)
    // exactly, in every variant and precision: 2 sequences × 3 frames of 4×5 images,
    // 12 inputs and 8 channels, actions 2 and 0 of a 3-row table.
    for mut v in Variant::all() {
        let a = v.wave("a", &[6, 8, 4, 5], 0.31);
        let tokens = v.wave("tokens", &[2, 20, 3, 12], 0.53);
        let weight = v.wave("weight", &[8, 12], 0.29);
        let bias = v.wave("bias", &[8], 0.61);
        let table = v.wave("table", &[3, 8], 0.77);
        let what = v.name();
        let mut r = v.recorder();
        let ids = r.indices("ids", &[2, 0]).unwrap();
        let spatial_tokens = tokens.reshaped(&[6, 20, 12]);
        let spatial = r
            .linear_to_images(
                &spatial_tokens,
                (&weight, &bias),
                &a,
                1,
                Some((&table, &ids, 3)),
            )
            .unwrap();
        let temporal = r
            .linear_to_images(&tokens, (&weight, &bias), &a, 3, None)
            .unwrap();
        let out = r.linear(&spatial_tokens, &weight, &bias, false).unwrap();
        let spatial_ops = r
            .add_permuted_bias(
                &a,
                &out,
                [1, 6, 20, 8],
                [0, 1, 3, 2],
                Some((&table, &ids, 3)),
            )
            .unwrap();
        let temporal_ops = r
            .add_permuted(&a, &out, [2, 20, 3, 8], [0, 2, 3, 1])
            .unwrap();
        r.submit();
        assert_eq!(spatial.shape, vec![6, 8, 4, 5]);
        assert_same_bits(v.precision, &v.read(&spatial), &v.read(&spatial_ops), &what);
        assert_same_bits(
            v.precision,
            &v.read(&temporal),
            &v.read(&temporal_ops),
            &format!("{what} frames"),
        );
        assert!(
            worst_difference(&v.read(&temporal), &v.read(&spatial)) > 0.1,
            "{what}: the bias and the layouts differ"
        );
    }
}

/// `linear_rows` of `rows` × 12 values to `outputs` outputs with a layer norm, the row
/// `order` and a residual (fused), and with none of them (plain), against gather, layer
/// norm (the group norm with one group per row) and linear plus residual, and a plain
/// linear layer: the gather and norm by the variant's kernels, the linear layers by
/// `reference` (the variant's own when None). Asserts the same bits; returns the fused
/// and plain results.
fn rows_against_separate_ops(
    v: &mut Variant,
    rows: usize,
    outputs: usize,
    order: &[u32],
    reference: Option<Kernels>,
    what: &str,
) -> (Vec<f32>, Vec<f32>) {
    let x = v.wave("x", &[rows, 12], 0.37);
    let weight = v.wave("weight", &[outputs, 12], 0.29);
    let bias = v.wave("bias", &[outputs], 0.61);
    let gamma = v.wave("gamma", &[12], 0.7);
    let beta = v.wave("beta", &[12], 0.9);
    let residual = v.wave("residual", &[rows, outputs], 0.47);
    let mut r = v.recorder();
    let order = r.indices("order", order).unwrap();
    let layer = (&weight, &bias);
    let norm = Some((&gamma, &beta));
    let fused = r
        .linear_rows(&x, layer, norm, Some(&order), Some(&residual))
        .unwrap();
    let plain = r.linear_rows(&x, layer, None, None, None).unwrap();
    let gathered = r.gather(&x, &order).unwrap();
    let normed = r
        .group_norm(
            &gathered.reshaped(&[rows, 12, 1, 1]),
            &gamma,
            &beta,
            1,
            false,
        )
        .unwrap()
        .reshaped(&[rows, 12]);
    if let Some(kernels) = reference {
        r.set_kernels(kernels);
    }
    let separate = r
        .linear_plus(&normed, &weight, &bias, false, Some(&residual))
        .unwrap();
    let plain_ops = r.linear(&x, &weight, &bias, false).unwrap();
    r.submit();
    let (fused, plain) = (v.read(&fused), v.read(&plain));
    assert_same_bits(v.precision, &fused, &v.read(&separate), what);
    let what = format!("{what} plain");
    assert_same_bits(v.precision, &plain, &v.read(&plain_ops), &what);
    (fused, plain)
}

#[test]
fn the_linear_layer_over_gathered_normed_rows_equals_the_separate_ops_bit_for_bit() {
    // The refiner's layer norm, projection and serialisation gather in one dispatch on
    // CPU drivers must equal gather, layer norm and linear (plus residual) exactly, in
    // every variant and precision: 11 rows of 12 values (a partial 8-row tile) in a
    // scrambled order, 8 outputs.
    for mut v in Variant::all() {
        let what = v.name();
        let order = [3, 7, 0, 10, 1, 9, 2, 8, 4, 6, 5];
        let (fused, plain) = rows_against_separate_ops(&mut v, 11, 8, &order, None, &what);
        assert!(
            worst_difference(&fused, &plain) > 0.1,
            "{what}: the norm and the order changed the result"
        );
    }
}

#[test]
fn the_linear_layer_over_many_outputs_equals_the_simple_kernel_bit_for_bit() {
    // The CPU variant stores plain rows four outputs at a time where the outputs allow
    // (linear_rows_cpu.wgsl), one at a time otherwise (linear_cpu.wgsl), and with a
    // layer norm makes a chunk of output tiles per invocation: both must give the
    // simple kernel's bits after the same gather and norm. 19 rows (a partial tile),
    // 12 inputs; 44 outputs (six tiles, the last half full: a full chunk and a partial
    // one) and 42 (the one-value stores), with and without norm, order and residual.
    for mut v in Variant::all() {
        let order: Vec<u32> = (0..19).map(|i| (i * 7) % 19).collect();
        for outputs in [44, 42] {
            let what = format!("{} {outputs} outputs", v.name());
            let simple = Some(Kernels::Simple);
            rows_against_separate_ops(&mut v, 19, outputs, &order, simple, &what);
        }
    }
}

#[test]
fn the_linear_layer_with_its_residual_equals_a_separate_add_bit_for_bit() {
    // The refiner's `x + proj(a)` and `x + fc2(silu(h))`: the residual in the linear
    // kernels' epilogue equals linear then add.wgsl, in every variant and precision, for
    // 7 rows (a partial tile) and 1 row (one output per invocation in the simple
    // variant; a mostly clamped 8 × 8 texel tile in the CPU variant).
    for mut v in Variant::all() {
        let weight = v.wave("w", &[12, 8], 0.29);
        let bias = v.wave("b", &[12], 0.5);
        for rows in [7, 1] {
            let x = v.wave("x", &[rows, 8], 0.13);
            let res = v.wave("res", &[rows, 12], 0.71);
            let mut r = v.recorder();
            let fused = r.linear_plus(&x, &weight, &bias, true, Some(&res)).unwrap();
            let plain = r.linear(&x, &weight, &bias, true).unwrap();
            let separate = r.add(&res, &plain, Broadcast::Trailing).unwrap();
            r.submit();
            let (a, b) = (v.read(&fused), v.read(&separate));
            assert_same_bits(v.precision, &a, &b, &format!("{} {rows} rows", v.name()));
        }
    }
}

#[test]
fn the_linear_layer_over_few_rows_equals_the_simple_kernel_bit_for_bit() {
    // The CPU variant runs 1-3 rows (the embeddings, the PCA head's basis product) in its
    // 8 × 8 texel tiles, which sum in the simple kernel's order: the same bits. 20
    // inputs (five texels), 13 outputs (a partial tile), with and without SiLU.
    for mut v in Variant::all() {
        let weight = v.wave("w", &[13, 20], 0.31);
        let bias = v.wave("b", &[13], 0.6);
        for rows in [1, 2, 3] {
            let x = v.wave("x", &[rows, 20], 0.17);
            for silu in [false, true] {
                let mut r = v.recorder();
                let tiled = r.linear(&x, &weight, &bias, silu).unwrap();
                r.set_kernels(Kernels::Simple);
                let simple = r.linear(&x, &weight, &bias, silu).unwrap();
                r.submit();
                let (a, b) = (v.read(&tiled), v.read(&simple));
                let what = format!("{} {rows} rows, silu {silu}", v.name());
                assert_same_bits(v.precision, &a, &b, &what);
            }
        }
    }
}
