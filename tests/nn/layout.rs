use super::*;

#[test]
fn the_permute_with_its_addends_equals_the_separate_ops_bit_for_bit() {
    // The spatial attention's residual (a + permuted tokens) and the cross-attention's
    // action bias in one pass must equal add_permuted then add_action_bias exactly, in
    // every precision (one kernel serves every variant): 2 samples × 3 frames of 4×5
    // images with 8 channels, actions 2 and 0 of a 3-row table.
    for mut v in Variant::all() {
        let a = v.wave("a", &[6, 8, 4, 5], 0.31);
        let tokens = v.wave("tokens", &[6, 20, 8], 0.53);
        let table = v.wave("table", &[3, 8], 0.77);
        let mut r = v.recorder();
        let ids = r.indices("ids", &[2, 0]).unwrap();
        let (shape, perm) = ([1, 6, 20, 8], [0, 1, 3, 2]);
        let fused = r
            .add_permuted_bias(&a, &tokens, shape, perm, Some((&table, &ids, 3)))
            .unwrap();
        let sum = r.add_permuted(&a, &tokens, shape, perm).unwrap();
        let separate = r.add_action_bias(&sum, &table, &ids, 3).unwrap();
        r.submit();
        let (x, y) = (v.read(&fused), v.read(&separate));
        let plain = v.read(&sum);
        assert_same_bits(v.precision, &x, &y, &v.name());
        assert!(worst_difference(&x, &plain) > 0.1, "the bias was added");

        // The temporal layers' tokens: permuted, plus frame positions 1..4 of a 5-row
        // table repeated over the leading axes, equal to a permute then add_part.
        let positions = v.wave("positions", &[5, 8], 0.43);
        let mut r = v.recorder();
        let (shape, perm) = ([2, 3, 8, 20], [0, 3, 1, 2]);
        let fused = r
            .permute_add_rows(&a, shape, perm, &positions, 8..32)
            .unwrap();
        let permuted = r.permute(&a, shape, perm).unwrap();
        let separate = r
            .add_part(&permuted, &positions, 8..32, Broadcast::Trailing)
            .unwrap();
        r.submit();
        let (x, y) = (v.read(&fused), v.read(&separate));
        assert_eq!(fused.shape, vec![2, 20, 3, 8]);
        assert_same_bits(v.precision, &x, &y, &format!("{} rows", v.name()));
    }
}

#[test]
fn the_norm_stored_as_tokens_equals_the_norm_then_the_permute_bit_for_bit() {
    // The attention layers' group norm then permute to token rows (spatial: one frame;
    // temporal: 3 frames with positions 1..4 of a 5-row table) in one dispatch on CPU
    // drivers must equal group_norm then permute(_add_rows) exactly, in every variant
    // and precision: 2 sequences × 3 frames of 4×5 images with 8 channels in 4 groups.
    for mut v in Variant::all() {
        let x = v.wave("x", &[6, 8, 4, 5], 0.31);
        let gamma = v.wave("gamma", &[8], 0.7);
        let beta = v.wave("beta", &[8], 0.9);
        let positions = v.wave("positions", &[5, 8], 0.43);
        let what = v.name();
        let mut r = v.recorder();
        let spatial = r
            .group_norm_tokens(&x, (&gamma, &beta, 4), 1, None)
            .unwrap();
        let temporal = r
            .group_norm_tokens(&x, (&gamma, &beta, 4), 3, Some((&positions, 8..32)))
            .unwrap();
        let normed = r.group_norm(&x, &gamma, &beta, 4, false).unwrap();
        let spatial_ops = r.permute(&normed, [6, 1, 8, 20], [0, 3, 1, 2]).unwrap();
        let temporal_ops = r
            .permute_add_rows(&normed, [2, 3, 8, 20], [0, 3, 1, 2], &positions, 8..32)
            .unwrap();
        r.submit();
        assert_eq!(spatial.shape, vec![6, 20, 1, 8]);
        assert_eq!(temporal.shape, vec![2, 20, 3, 8]);
        assert_same_bits(v.precision, &v.read(&spatial), &v.read(&spatial_ops), &what);
        assert_same_bits(
            v.precision,
            &v.read(&temporal),
            &v.read(&temporal_ops),
            &format!("{what} rows"),
        );
        assert!(
            worst_difference(&v.read(&temporal), &v.read(&spatial)) > 0.1,
            "{what}: the layouts differ"
        );
    }
}
