use super::*;

#[test]
fn the_last_frame_from_cached_rows_equals_the_whole_group() {
    // Causality: frames 0-2 run alone (rows kept), then frame 3 alone against the kept
    // rows, must give the whole group's frame 3. x [8, 16, 4, 4] = 2 groups × 4 frames.
    let mut f = Fixture::open("temporal_attention", Precision::F32);
    let (values, _) = f.stored("io.in.x");
    let frame = 16 * 4 * 4;
    let pick = |frames: std::ops::Range<usize>| -> Vec<f32> {
        (0..2)
            .flat_map(|g| {
                values[(4 * g + frames.start) * frame..(4 * g + frames.end) * frame].to_vec()
            })
            .collect()
    };
    let context = Tensor::upload(
        &f.gpu,
        "context",
        &[6, 16, 4, 4],
        &pick(0..3),
        Precision::F32,
    )
    .unwrap();
    let last = Tensor::upload(&f.gpu, "last", &[2, 16, 4, 4], &pick(3..4), Precision::F32).unwrap();
    let (mut r, w) = f.recorder();
    let layer = TemporalAttention::load(&w, 16, 4, 2).unwrap();
    let mut kept = Vec::new();
    let frames = Frames::First {
        count: 3,
        keep: Some(&mut kept),
    };
    layer.forward(&mut r, &context, frames).unwrap();
    let y = layer
        .forward(&mut r, &last, Frames::Next { cached: &kept[0] })
        .unwrap();
    r.submit();
    let got = y.read(&f.gpu).unwrap();
    let want: Vec<f32> = {
        let (out, _) = f.stored("io.out.y");
        (0..2)
            .flat_map(|g| out[(4 * g + 3) * frame..(4 * g + 4) * frame].to_vec())
            .collect()
    };
    let worst = worst_difference(&got, &want);
    assert!(worst <= 1e-4, "{worst}");
}

#[test]
fn attention_over_a_cached_prefix_equals_attention_over_the_concatenation_bit_for_bit() {
    // The temporal layers' target pass: 3 cached frames' packed qkv rows and 1 new frame,
    // causal, 2 heads of 8 — read in place must equal reading their concatenation, in
    // every kernel variant and precision (head 8: the CPU variant applies).
    let (sequences, cached_keys, c) = (6usize, 3usize, 16usize);
    for mut v in Variant::all() {
        let cached = v.wave("cached", &[1, sequences, cached_keys, 3 * c], 0.37);
        let fresh = v.wave("fresh", &[1, sequences, 1, 3 * c], 0.61);
        let params = unica::nn::ops::AttentionParams {
            sequences: sequences as u32,
            heads: 2,
            queries: 1,
            keys: (cached_keys + 1) as u32,
            channels: c as u32,
            q_stride: (3 * c) as u32,
            q_offset: 0,
            kv_stride: (3 * c) as u32,
            k_offset: c as u32,
            v_offset: (2 * c) as u32,
            causal: 1,
            kv_share: 1,
            prefix_keys: 0,
            rows: 0,
            reserved1: 0,
            reserved2: 0,
        };
        let mut r = v.recorder();
        let joined = r.concat(&cached, &fresh, 2).unwrap();
        let whole = r.attention(&fresh, &joined, params).unwrap();
        let in_place = r
            .attention_after(
                &fresh,
                Some(&cached),
                &fresh,
                unica::nn::ops::AttentionParams {
                    prefix_keys: cached_keys as u32,
                    ..params
                },
            )
            .unwrap();
        r.submit();
        let (a, b) = (v.read(&whole), v.read(&in_place));
        assert_same_bits(v.precision, &a, &b, &v.name());
    }
}

#[test]
fn the_one_frame_temporal_attention_equals_the_projection_then_the_attention_bit_for_bit() {
    // A temporal layer's step for one new frame (each sequence projects its own q, k and
    // v, then attends over 3 cached rows and its own) in one dispatch on CPU drivers must
    // equal linear then attention_after exactly, in every variant and precision: 6
    // sequences, heads of 8 values (16 channels) and of 24 (48 channels, the wide path).
    for mut v in Variant::all() {
        for c in [16, 48] {
            let tokens = v.wave("tokens", &[6, 1, c], 0.37);
            let weight = v.wave("weight", &[3 * c, c], 0.29);
            let bias = v.wave("bias", &[3 * c], 0.61);
            let cached = v.wave("cached", &[6, 3, 3 * c], 0.53);
            let params = AttentionParams {
                sequences: 6,
                heads: 2,
                queries: 1,
                keys: 4,
                channels: c as u32,
                q_stride: 3 * c as u32,
                q_offset: 0,
                kv_stride: 3 * c as u32,
                k_offset: c as u32,
                v_offset: 2 * c as u32,
                causal: 1,
                kv_share: 1,
                prefix_keys: 3,
                rows: 0,
                reserved1: 0,
                reserved2: 0,
            };
            let mut r = v.recorder();
            let fused = r
                .temporal_next(&tokens, (&weight, &bias), &cached, params)
                .unwrap();
            let qkv = r.linear(&tokens, &weight, &bias, false).unwrap();
            let separate = r
                .attention_after(&qkv, Some(&cached), &qkv, params)
                .unwrap();
            r.submit();
            let what = format!("{} {c} channels", v.name());
            assert_eq!(fused.shape, separate.shape, "{what}");
            let (x, y) = (v.read(&fused), v.read(&separate));
            assert_same_bits(v.precision, &x, &y, &what);
        }
    }
}

#[test]
fn the_action_table_gives_the_cross_attention_bit_for_bit() {
    // One token per sample: the UNet's table lookup must equal the layer exactly, in
    // every kernel variant and precision (and the layer itself matches PyTorch above).
    for (precision, kernels) in variants() {
        let mut f = Fixture::open("cross_attention", precision);
        let (x, ctx) = (f.input("io.in.x"), f.input("io.in.ctx"));
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let layer = CrossAttention::load(&w, 16, 32, 2).unwrap();
        let full = layer.forward(&mut r, &x, &ctx).unwrap();
        let table = layer.action_table(&mut r, &ctx.reshaped(&[2, 32])).unwrap();
        let ids = r.indices("ids", &[0, 1]).unwrap();
        let looked_up = r.add_action_bias(&x, &table, &ids, 1).unwrap();
        r.submit();
        let (a, b) = (full.read(&f.gpu).unwrap(), looked_up.read(&f.gpu).unwrap());
        assert_same_bits(precision, &a, &b, &format!("{precision:?} {kernels:?}"));
    }
}

#[test]
fn attention_over_odd_runs_and_causal_keys_matches_the_simple_kernel() {
    // The CPU variant gives two neighbouring queries of a run to one invocation: odd runs
    // (the pair's second is no query), causal runs (the pair's queries see different
    // keys), runs cut at `rows` (the refiner's last patch, odd and shorter), a cached
    // prefix, and heads of 8 and 24 values (the narrow and wide loops) must all match
    // the simple kernel, in every variant and precision (sums in another order: within
    // 2e-6, 4e-3 in f16).
    struct Case {
        what: &'static str,
        sequences: u32,
        queries: u32,
        keys: u32,
        prefix: u32,
        causal: u32,
        rows: u32,
    }
    let cases = [
        Case {
            what: "odd run",
            sequences: 3,
            queries: 7,
            keys: 7,
            prefix: 0,
            causal: 0,
            rows: 0,
        },
        Case {
            what: "causal",
            sequences: 2,
            queries: 5,
            keys: 5,
            prefix: 0,
            causal: 1,
            rows: 0,
        },
        Case {
            what: "rows cut",
            sequences: 3,
            queries: 6,
            keys: 6,
            prefix: 0,
            causal: 0,
            rows: 15,
        },
        Case {
            what: "prefix",
            sequences: 2,
            queries: 3,
            keys: 5,
            prefix: 2,
            causal: 1,
            rows: 0,
        },
    ];
    for head in [8u32, 24] {
        let (heads, c) = (2u32, 2 * head);
        for case in &cases {
            for mut v in Variant::all() {
                let fresh_keys = case.keys - case.prefix;
                let run = case.queries.max(fresh_keys);
                let q = v.wave(
                    "q",
                    &[(case.sequences * run) as usize, (3 * c) as usize],
                    0.37,
                );
                let cached = v.wave(
                    "cached",
                    &[
                        (case.sequences * case.prefix.max(1)) as usize,
                        (3 * c) as usize,
                    ],
                    0.61,
                );
                let params = unica::nn::ops::AttentionParams {
                    sequences: case.sequences,
                    heads,
                    queries: case.queries,
                    keys: case.keys,
                    channels: c,
                    q_stride: 3 * c,
                    q_offset: 0,
                    kv_stride: 3 * c,
                    k_offset: c,
                    v_offset: 2 * c,
                    causal: case.causal,
                    kv_share: 1,
                    prefix_keys: case.prefix,
                    rows: case.rows,
                    reserved1: 0,
                    reserved2: 0,
                };
                let prefix = (case.prefix > 0).then_some(&cached);
                let mut r = v.recorder();
                let got = r.attention_after(&q, prefix, &q, params).unwrap();
                r.set_kernels(Kernels::Simple);
                let want = r.attention_after(&q, prefix, &q, params).unwrap();
                r.submit();
                let (got, want) = (v.read(&got), v.read(&want));
                let limit = match v.precision {
                    Precision::F32 => 2e-6,
                    _ => 4e-3,
                };
                let worst = worst_difference(&got, &want);
                let what = format!("{} {} head {head}: {worst}", v.name(), case.what);
                assert!(worst <= limit, "{what}");
                assert!(want.iter().any(|x| x.abs() > 0.1), "{what}: no output");
            }
        }
    }
}
