//! CPU inference of the auto-rigger's two models, weight for weight as the PyTorch
//! trainer defines them (train/unica_train/rig.py): the skeleton-token predictor (a
//! point-cloud encoder to M latents, then a causal transformer over [latents; tokens],
//! decoded token by token with a KV cache under the grammar of [`TokenDecoder`]) and the skin
//! model (softmax over bones of a learned vertex-bone score plus geodesic and
//! bone-distance priors). Plain f32 on one CPU thread: the auto-rigger runs on the
//! teacher side, once per character. Every attention and MLP block is pre-LN with a
//! residual; GELU is the tanh approximation; activations are row-major `Vec<f32>`s.

use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::Deserialize;
use serde::de::DeserializeOwned;

use super::skeleton::{Class, Skeleton};
use super::tokens::{self, BINS, BOS, CLASS_OTHER, EOS, TokenDecoder, TokenError, VOCAB};
use crate::random::Rng;
use crate::tensors::{TensorError, TensorFile};

/// Fourier frequencies per coordinate.
const FREQUENCIES: usize = 6;
/// Fourier features of a point: itself, then sines and cosines: 3 + 2·3·6 = 39 values.
const FOURIER: usize = 3 + 6 * FREQUENCIES;
const LN_EPS: f32 = 1e-5;

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Tensor(#[from] TensorError),
    #[error("{}: {problem}", path.display())]
    Config { path: PathBuf, problem: String },
    #[error("{tokens} tokens, more than the model's {max_len} positions")]
    TooLong { tokens: usize, max_len: usize },
    #[error("token {0} is outside the vocabulary")]
    OutOfVocabulary(u32),
    #[error("no skeleton fits in the model's {0} positions")]
    NoRoom(usize),
    #[error(transparent)]
    Grammar(#[from] TokenError),
}

// ------------------------------------------------------------------------ pieces

fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for ((l, x), y) in lanes.iter_mut().zip(x).zip(y) {
            *l += x * y;
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// GELU, tanh approximation.
fn gelu_all(x: Vec<f32>) -> Vec<f32> {
    const SQRT_2_OVER_PI: f32 = 0.797_884_6;
    x.into_iter()
        .map(|x| 0.5 * x * (1.0 + (SQRT_2_OVER_PI * (x + 0.044_715 * x * x * x)).tanh()))
        .collect()
}

fn add(x: &[f32], y: &[f32]) -> Vec<f32> {
    x.iter().zip(y).map(|(a, b)| a + b).collect()
}

/// The columns `range` of each `width`-wide row.
fn columns(x: &[f32], width: usize, range: Range<usize>) -> Vec<f32> {
    x.chunks_exact(width)
        .flat_map(|row| &row[range.clone()])
        .copied()
        .collect()
}

/// Appends p, then sin(2^k π p) for k = 0..5 (three coordinates each), then cos likewise.
fn fourier(p: Vec3, out: &mut Vec<f32>) {
    let p = p.to_array();
    out.extend(p);
    for f in [f32::sin, f32::cos] {
        for k in 0..FREQUENCIES {
            let w = (1u32 << k) as f32 * std::f32::consts::PI;
            out.extend(p.map(|x| f(x * w)));
        }
    }
}

fn softmax(x: &mut [f32]) {
    let max = x.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    let mut total = 0.0;
    for v in x.iter_mut() {
        *v = (*v - max).exp();
        total += *v;
    }
    x.iter_mut().for_each(|v| *v /= total);
}

/// Multi-head softmax attention of query rows over key/value rows, all `d` wide: query row
/// `i` sees key row `j` when `visible(i, j)`; heads concatenated.
fn attention(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    d: usize,
    heads: usize,
    visible: impl Fn(usize, usize) -> bool,
) -> Vec<f32> {
    let hd = d / heads;
    let root = (hd as f32).sqrt();
    let mut out = vec![0.0; q.len()];
    let mut scores = vec![0.0; k.len() / d];
    for (i, (q_row, o_row)) in q.chunks_exact(d).zip(out.chunks_exact_mut(d)).enumerate() {
        for h in (0..d).step_by(hd) {
            for (j, s) in scores.iter_mut().enumerate() {
                *s = if visible(i, j) {
                    dot(&q_row[h..h + hd], &k[j * d + h..j * d + h + hd]) / root
                } else {
                    f32::NEG_INFINITY
                };
            }
            softmax(&mut scores);
            let o = &mut o_row[h..h + hd];
            for (j, &w) in scores.iter().enumerate().filter(|(_, w)| **w > 0.0) {
                for (o, v) in o.iter_mut().zip(&v[j * d + h..j * d + h + hd]) {
                    *o += w * v;
                }
            }
        }
    }
    out
}

struct Linear {
    weight: Vec<f32>,
    bias: Vec<f32>,
    inputs: usize,
}

impl Linear {
    fn load(
        file: &TensorFile,
        name: &str,
        outputs: usize,
        inputs: usize,
    ) -> Result<Self, TensorError> {
        Ok(Self {
            weight: file
                .f32(&format!("{name}.weight"), &[Some(outputs), Some(inputs)])?
                .0,
            bias: file.f32(&format!("{name}.bias"), &[Some(outputs)])?.0,
            inputs,
        })
    }

    /// x W^T + b for each row of x.
    fn apply(&self, x: &[f32]) -> Vec<f32> {
        let mut y = Vec::with_capacity(x.len() / self.inputs * self.bias.len());
        for row in x.chunks_exact(self.inputs) {
            for (w, b) in self.weight.chunks_exact(self.inputs).zip(&self.bias) {
                y.push(dot(row, w) + b);
            }
        }
        y
    }
}

struct Norm {
    weight: Vec<f32>,
    bias: Vec<f32>,
}

impl Norm {
    fn load(file: &TensorFile, name: &str, d: usize) -> Result<Self, TensorError> {
        Ok(Self {
            weight: file.f32(&format!("{name}.weight"), &[Some(d)])?.0,
            bias: file.f32(&format!("{name}.bias"), &[Some(d)])?.0,
        })
    }

    fn apply(&self, x: &[f32]) -> Vec<f32> {
        let d = self.weight.len();
        let mut y = Vec::with_capacity(x.len());
        for row in x.chunks_exact(d) {
            let mean = row.iter().sum::<f32>() / d as f32;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / d as f32;
            let inv = 1.0 / (var + LN_EPS).sqrt();
            for ((v, w), b) in row.iter().zip(&self.weight).zip(&self.bias) {
                y.push((v - mean) * inv * w + b);
            }
        }
        y
    }
}

/// Linear, GELU, Linear (names `.0` and `.2`).
struct Embed {
    first: Linear,
    second: Linear,
}

impl Embed {
    fn load(file: &TensorFile, name: &str, inputs: usize, d: usize) -> Result<Self, TensorError> {
        Ok(Self {
            first: Linear::load(file, &format!("{name}.0"), d, inputs)?,
            second: Linear::load(file, &format!("{name}.2"), d, d)?,
        })
    }

    fn apply(&self, x: &[f32]) -> Vec<f32> {
        self.second.apply(&gelu_all(self.first.apply(x)))
    }
}

/// Keys and values of the rows a self-attention has seen so far.
#[derive(Default)]
struct Cache {
    keys: Vec<f32>,
    values: Vec<f32>,
}

struct SelfAttention {
    ln: Norm,
    qkv: Linear,
    out: Linear,
    heads: usize,
}

impl SelfAttention {
    fn load(file: &TensorFile, name: &str, d: usize, heads: usize) -> Result<Self, TensorError> {
        Ok(Self {
            ln: Norm::load(file, &format!("{name}.ln"), d)?,
            qkv: Linear::load(file, &format!("{name}.qkv"), 3 * d, d)?,
            out: Linear::load(file, &format!("{name}.out"), d, d)?,
            heads,
        })
    }

    /// x + attention of x's rows over the cached rows and themselves (their keys and values
    /// join the cache); row r of the whole sequence sees row c when `visible(r, c)`.
    fn apply(
        &self,
        x: &[f32],
        cache: &mut Cache,
        visible: impl Fn(usize, usize) -> bool,
    ) -> Vec<f32> {
        let d = self.out.inputs;
        let first = cache.keys.len() / d;
        let qkv = self.qkv.apply(&self.ln.apply(x));
        cache.keys.extend(columns(&qkv, 3 * d, d..2 * d));
        cache.values.extend(columns(&qkv, 3 * d, 2 * d..3 * d));
        let q = columns(&qkv, 3 * d, 0..d);
        let o = attention(&q, &cache.keys, &cache.values, d, self.heads, |i, j| {
            visible(first + i, j)
        });
        add(x, &self.out.apply(&o))
    }

    /// Every row sees every row.
    fn apply_unmasked(&self, x: &[f32]) -> Vec<f32> {
        self.apply(x, &mut Cache::default(), |_, _| true)
    }
}

struct CrossAttention {
    ln_q: Norm,
    ln_kv: Norm,
    q: Linear,
    kv: Linear,
    out: Linear,
    heads: usize,
}

impl CrossAttention {
    fn load(file: &TensorFile, name: &str, d: usize, heads: usize) -> Result<Self, TensorError> {
        Ok(Self {
            ln_q: Norm::load(file, &format!("{name}.ln_q"), d)?,
            ln_kv: Norm::load(file, &format!("{name}.ln_kv"), d)?,
            q: Linear::load(file, &format!("{name}.q"), d, d)?,
            kv: Linear::load(file, &format!("{name}.kv"), 2 * d, d)?,
            out: Linear::load(file, &format!("{name}.out"), d, d)?,
            heads,
        })
    }

    /// x + attention of x's rows over the context rows.
    fn apply(&self, x: &[f32], context: &[f32]) -> Vec<f32> {
        let d = self.out.inputs;
        let q = self.q.apply(&self.ln_q.apply(x));
        let kv = self.kv.apply(&self.ln_kv.apply(context));
        let (k, v) = (columns(&kv, 2 * d, 0..d), columns(&kv, 2 * d, d..2 * d));
        let o = attention(&q, &k, &v, d, self.heads, |_, _| true);
        add(x, &self.out.apply(&o))
    }
}

struct Mlp {
    ln: Norm,
    fc1: Linear,
    fc2: Linear,
}

impl Mlp {
    fn load(file: &TensorFile, name: &str, d: usize) -> Result<Self, TensorError> {
        Ok(Self {
            ln: Norm::load(file, &format!("{name}.ln"), d)?,
            fc1: Linear::load(file, &format!("{name}.fc1"), 4 * d, d)?,
            fc2: Linear::load(file, &format!("{name}.fc2"), d, 4 * d)?,
        })
    }

    fn apply(&self, x: &[f32]) -> Vec<f32> {
        let hidden = gelu_all(self.fc1.apply(&self.ln.apply(x)));
        add(x, &self.fc2.apply(&hidden))
    }
}

/// `dir/{kind}_config.json` and `dir/{kind}.safetensors`.
fn open<C: DeserializeOwned>(dir: &Path, kind: &str) -> Result<(C, TensorFile), ModelError> {
    let path = dir.join(format!("{kind}_config.json"));
    let fail = |problem: String| ModelError::Config {
        path: path.clone(),
        problem,
    };
    let text = std::fs::read_to_string(&path).map_err(|e| fail(e.to_string()))?;
    let config = serde_json::from_str(&text).map_err(|e| fail(e.to_string()))?;
    Ok((
        config,
        TensorFile::open(&dir.join(format!("{kind}.safetensors")))?,
    ))
}

fn check_heads(dir: &Path, kind: &str, d: usize, heads: usize) -> Result<(), ModelError> {
    if d == 0 || heads == 0 || !d.is_multiple_of(heads) {
        return Err(ModelError::Config {
            path: dir.join(format!("{kind}_config.json")),
            problem: format!("width {d} does not split into {heads} heads"),
        });
    }
    Ok(())
}

// ------------------------------------------------------------ skeleton predictor

#[derive(Clone, Debug, Deserialize)]
pub struct SkeletonConfig {
    pub d: usize,
    pub heads: usize,
    /// M: latent rows the encoder leaves.
    pub latents: usize,
    /// L: decoder blocks.
    pub layers: usize,
    /// Positions of the token sequence (the longest sequence, eos included).
    pub max_len: usize,
}

pub struct SkeletonModel {
    config: SkeletonConfig,
    embed: Embed,
    latents: Vec<f32>,
    cross: CrossAttention,
    cross_mlp: Mlp,
    self_attn: SelfAttention,
    self_mlp: Mlp,
    tok_emb: Vec<f32>,
    pos_emb: Vec<f32>,
    blocks: Vec<(SelfAttention, Mlp)>,
    ln: Norm,
    head: Linear,
}

impl SkeletonModel {
    /// Reads `dir/skeleton_config.json` and `dir/skeleton.safetensors`.
    pub fn load(dir: &Path) -> Result<Self, ModelError> {
        let (config, file): (SkeletonConfig, _) = open(dir, "skeleton")?;
        let SkeletonConfig {
            d,
            heads,
            latents,
            layers,
            max_len,
        } = config;
        check_heads(dir, "skeleton", d, heads)?;
        Ok(Self {
            embed: Embed::load(&file, "encoder.embed", FOURIER + 3, d)?,
            latents: file.f32("encoder.latents", &[Some(latents), Some(d)])?.0,
            cross: CrossAttention::load(&file, "encoder.cross", d, heads)?,
            cross_mlp: Mlp::load(&file, "encoder.cross_mlp", d)?,
            self_attn: SelfAttention::load(&file, "encoder.self", d, heads)?,
            self_mlp: Mlp::load(&file, "encoder.self_mlp", d)?,
            tok_emb: file.f32("decoder.tok_emb", &[Some(VOCAB), Some(d)])?.0,
            pos_emb: file.f32("decoder.pos_emb", &[Some(max_len), Some(d)])?.0,
            blocks: (0..layers)
                .map(|i| {
                    let name = format!("decoder.blocks.{i}");
                    Ok((
                        SelfAttention::load(&file, &format!("{name}.attn"), d, heads)?,
                        Mlp::load(&file, &format!("{name}.mlp"), d)?,
                    ))
                })
                .collect::<Result<_, TensorError>>()?,
            ln: Norm::load(&file, "decoder.ln", d)?,
            head: Linear::load(&file, "decoder.head", VOCAB, d)?,
            config,
        })
    }

    pub fn config(&self) -> &SkeletonConfig {
        &self.config
    }

    /// The latents [M, d] of a point cloud (unit-cube points with their normals).
    fn encode(&self, points: &[Vec3], normals: &[Vec3]) -> Vec<f32> {
        assert_eq!(points.len(), normals.len(), "one normal per point");
        let mut features = Vec::with_capacity(points.len() * (FOURIER + 3));
        for (&p, n) in points.iter().zip(normals) {
            fourier(p, &mut features);
            features.extend(n.to_array());
        }
        let h = self.embed.apply(&features);
        let x = self.cross_mlp.apply(&self.cross.apply(&self.latents, &h));
        self.self_mlp.apply(&self.self_attn.apply_unmasked(&x))
    }

    /// tok_emb[t] + pos_emb[position] for tokens at positions `first`...
    fn embed_tokens(&self, tokens: &[u32], first: usize) -> Result<Vec<f32>, ModelError> {
        let (d, max_len) = (self.config.d, self.config.max_len);
        if first + tokens.len() > max_len {
            return Err(ModelError::TooLong {
                tokens: first + tokens.len(),
                max_len,
            });
        }
        let mut x = Vec::with_capacity(tokens.len() * d);
        for (i, &token) in tokens.iter().enumerate() {
            let t = token as usize;
            if t >= VOCAB {
                return Err(ModelError::OutOfVocabulary(token));
            }
            let position = first + i;
            x.extend(add(
                &self.tok_emb[t * d..][..d],
                &self.pos_emb[position * d..][..d],
            ));
        }
        Ok(x)
    }

    /// New rows of [latents; tokens] through the decoder blocks, after the rows the caches
    /// hold: latent rows see the latents, token rows the latents and tokens up to their own.
    fn decode(&self, mut x: Vec<f32>, caches: &mut [Cache]) -> Vec<f32> {
        let m = self.config.latents;
        for ((attn, mlp), cache) in self.blocks.iter().zip(caches) {
            x = mlp.apply(&attn.apply(&x, cache, |r, c| c < m || c <= r));
        }
        x
    }

    /// Next-token logits of decoded token rows.
    fn head_logits(&self, x: &[f32]) -> Vec<[f32; VOCAB]> {
        let logits = self.head.apply(&self.ln.apply(x));
        logits
            .chunks_exact(VOCAB)
            .map(|row| {
                let mut out = [0.0; VOCAB];
                out.copy_from_slice(row);
                out
            })
            .collect()
    }

    /// The whole forward pass at once (the trainer's): next-token logits after each token.
    pub fn logits(
        &self,
        points: &[Vec3],
        normals: &[Vec3],
        tokens: &[u32],
    ) -> Result<Vec<[f32; VOCAB]>, ModelError> {
        let mut x = self.encode(points, normals);
        x.extend(self.embed_tokens(tokens, 0)?);
        let mut caches: Vec<Cache> = self.blocks.iter().map(|_| Cache::default()).collect();
        let y = self.decode(x, &mut caches);
        Ok(self.head_logits(&y[self.config.latents * self.config.d..]))
    }

    /// Encodes the point cloud once, for token-by-token decoding.
    pub fn start(&self, points: &[Vec3], normals: &[Vec3]) -> Decoding<'_> {
        let mut caches: Vec<Cache> = self.blocks.iter().map(|_| Cache::default()).collect();
        self.decode(self.encode(points, normals), &mut caches);
        Decoding {
            model: self,
            caches,
            position: 0,
        }
    }

    /// A token sequence for the point cloud, bos to eos, that the grammar accepts and that
    /// fits in `max_len`: the best token at each step (temperature 0) or samples of
    /// softmax(logits / temperature) from `seed`, among the tokens the grammar allows
    /// and after which the shortest way to finish still fits. `class`, when given, is
    /// the only class token allowed.
    pub fn predict_tokens(
        &self,
        points: &[Vec3],
        normals: &[Vec3],
        class: Option<Class>,
        temperature: f32,
        seed: u64,
    ) -> Result<Vec<u32>, ModelError> {
        let mut rng = Rng::new(seed);
        let mut grammar = TokenDecoder::new();
        let mut decoding = self.start(points, normals);
        let mut tokens = vec![BOS];
        grammar.push(BOS)?;
        let mut last = BOS;
        while !grammar.is_done() {
            let logits = decoding.step(last)?;
            let room = self.config.max_len.saturating_sub(tokens.len());
            let mut fits = fitting(&grammar, room);
            if let Some(class) = class.filter(|_| tokens.len() == 1) {
                let only = tokens::class_token(class) as usize;
                fits = std::array::from_fn(|t| t == only && fits[t]);
            }
            last = pick(&logits, &fits, temperature, &mut rng)
                .ok_or(ModelError::NoRoom(self.config.max_len))?;
            grammar.push(last)?;
            tokens.push(last);
        }
        Ok(tokens)
    }

    /// The skeleton of [`SkeletonModel::predict_tokens`] (unit-cube joints at bin centres).
    pub fn predict(
        &self,
        points: &[Vec3],
        normals: &[Vec3],
        class: Option<Class>,
        temperature: f32,
        seed: u64,
    ) -> Result<Skeleton, ModelError> {
        Ok(tokens::decode(&self.predict_tokens(
            points,
            normals,
            class,
            temperature,
            seed,
        )?)?)
    }
}

/// Token-by-token decoding with a KV cache per block (the latent rows already in).
pub struct Decoding<'m> {
    model: &'m SkeletonModel,
    caches: Vec<Cache>,
    position: usize,
}

impl Decoding<'_> {
    /// Feeds the next token; returns the logits of the one after it.
    pub fn step(&mut self, token: u32) -> Result<[f32; VOCAB], ModelError> {
        let x = self.model.embed_tokens(&[token], self.position)?;
        let y = self.model.decode(x, &mut self.caches);
        self.position += 1;
        Ok(self.model.head_logits(&y)[0])
    }
}

/// The shortest way on: eos when allowed, else any coordinate, else a class without a
/// template, else whatever the grammar allows.
fn shortest_next(allowed: &[bool; VOCAB]) -> Option<u32> {
    [EOS]
        .into_iter()
        .chain(0..BINS)
        .chain([CLASS_OTHER])
        .chain(0..VOCAB as u32)
        .find(|&t| allowed[t as usize])
}

/// Tokens the shortest completion of `grammar` takes, eos included.
fn shortest_completion(grammar: &TokenDecoder) -> Option<usize> {
    let mut d = grammar.clone();
    let mut n = 0;
    while !d.is_done() {
        d.push(shortest_next(&d.allowed())?).ok()?;
        n += 1;
    }
    Some(n)
}

/// The allowed tokens after which the sequence can still end within `room` tokens (this
/// one included).
fn fitting(grammar: &TokenDecoder, room: usize) -> [bool; VOCAB] {
    let allowed = grammar.allowed();
    let fits = |t: u32| {
        let mut d = grammar.clone();
        d.push(t).is_ok() && shortest_completion(&d).is_some_and(|n| n < room)
    };
    // Every allowed coordinate leads to the same kind of state: one stands for all.
    let coordinates = (0..BINS).find(|&t| allowed[t as usize]).is_some_and(fits);
    std::array::from_fn(|t| {
        allowed[t]
            && if t < BINS as usize {
                coordinates
            } else {
                fits(t as u32)
            }
    })
}

/// The best candidate (temperature 0) or a sample of softmax(logits / temperature) over the
/// candidates; `None` without any.
fn pick(
    logits: &[f32; VOCAB],
    candidates: &[bool; VOCAB],
    temperature: f32,
    rng: &mut Rng,
) -> Option<u32> {
    let ids = (0..VOCAB).filter(|&t| candidates[t]);
    let best = ids
        .clone()
        .max_by(|&a, &b| logits[a].total_cmp(&logits[b]))?;
    if temperature <= 0.0 {
        return Some(best as u32);
    }
    let weights: Vec<(usize, f32)> = ids
        .map(|t| (t, ((logits[t] - logits[best]) / temperature).exp()))
        .collect();
    let mut u = rng.uniform() as f32 * weights.iter().map(|(_, w)| w).sum::<f32>();
    for &(t, w) in &weights {
        if u <= w {
            return Some(t as u32);
        }
        u -= w;
    }
    Some(best as u32)
}

// -------------------------------------------------------------------- skin model

#[derive(Clone, Debug, Deserialize)]
pub struct SkinConfig {
    pub d: usize,
    pub heads: usize,
    /// The beta of the geodesic baseline softmax(-beta · geodesic), fit in training.
    pub baseline_beta: Option<f32>,
}

pub struct SkinModel {
    config: SkinConfig,
    vertex: Embed,
    context: Linear,
    bone: Embed,
    bone_attn: SelfAttention,
    bone_mlp: Mlp,
    ln_q: Norm,
    ln_k: Norm,
    q: Linear,
    k: Linear,
    prior_scale: f32,
    dist_scale: f32,
}

impl SkinModel {
    /// Reads `dir/skin_config.json` and `dir/skin.safetensors`.
    pub fn load(dir: &Path) -> Result<Self, ModelError> {
        let (config, file): (SkinConfig, _) = open(dir, "skin")?;
        let (d, heads) = (config.d, config.heads);
        check_heads(dir, "skin", d, heads)?;
        let scalar = |name: &str| Ok::<_, TensorError>(file.f32(name, &[Some(1)])?.0[0]);
        Ok(Self {
            vertex: Embed::load(&file, "skin.vertex", FOURIER + 3, d)?,
            context: Linear::load(&file, "skin.context", d, d)?,
            bone: Embed::load(&file, "skin.bone", 2 * FOURIER, d)?,
            bone_attn: SelfAttention::load(&file, "skin.bone_attn", d, heads)?,
            bone_mlp: Mlp::load(&file, "skin.bone_mlp", d)?,
            ln_q: Norm::load(&file, "skin.ln_q", d)?,
            ln_k: Norm::load(&file, "skin.ln_k", d)?,
            q: Linear::load(&file, "skin.q", d, d)?,
            k: Linear::load(&file, "skin.k", d, d)?,
            prior_scale: scalar("skin.prior_scale")?,
            dist_scale: scalar("skin.dist_scale")?,
            config,
        })
    }

    pub fn config(&self) -> &SkinConfig {
        &self.config
    }

    /// Skin weights [V][J] (each row sums to 1) of unit-cube vertices with their normals,
    /// for bones from `joints[b]` to `tails[b]`; `geodesic` is [V, J] row-major (the voxel
    /// geodesic distance of each vertex from each bone).
    pub fn weights(
        &self,
        vertices: &[Vec3],
        normals: &[Vec3],
        joints: &[Vec3],
        tails: &[Vec3],
        geodesic: &[f32],
    ) -> Vec<Vec<f32>> {
        let (d, bones) = (self.config.d, joints.len());
        assert_eq!(vertices.len(), normals.len(), "one normal per vertex");
        assert_eq!(bones, tails.len(), "one tail per joint");
        assert_eq!(geodesic.len(), vertices.len() * bones, "geodesic is [V, J]");
        let mut features = Vec::with_capacity(vertices.len() * (FOURIER + 3));
        for (&v, n) in vertices.iter().zip(normals) {
            fourier(v, &mut features);
            features.extend(n.to_array());
        }
        let mut hv = self.vertex.apply(&features);
        let mut global = vec![f32::NEG_INFINITY; d];
        for row in hv.chunks_exact(d) {
            global.iter_mut().zip(row).for_each(|(g, h)| *g = g.max(*h));
        }
        let context = self.context.apply(&global);
        for row in hv.chunks_exact_mut(d) {
            row.iter_mut().zip(&context).for_each(|(h, c)| *h += c);
        }
        let mut features = Vec::with_capacity(bones * 2 * FOURIER);
        for (&j, &t) in joints.iter().zip(tails) {
            fourier(j, &mut features);
            fourier(t, &mut features);
        }
        let hb = self
            .bone_mlp
            .apply(&self.bone_attn.apply_unmasked(&self.bone.apply(&features)));
        let q = self.q.apply(&self.ln_q.apply(&hv));
        let k = self.k.apply(&self.ln_k.apply(&hb));
        let root = (d as f32).sqrt();
        vertices
            .iter()
            .zip(q.chunks_exact(d))
            .zip(geodesic.chunks(bones.max(1)))
            .map(|((&v, q), geodesic)| {
                let mut row: Vec<f32> = (0..bones)
                    .map(|b| {
                        dot(q, &k[b * d..][..d]) / root
                            + self.prior_scale * geodesic[b]
                            + self.dist_scale * segment_distance(v, joints[b], tails[b])
                    })
                    .collect();
                softmax(&mut row);
                row
            })
            .collect()
    }
}

/// Distance from `v` to the segment a-b (sqrt(|.|² + 1e-12), as the trainer computes it).
fn segment_distance(v: Vec3, a: Vec3, b: Vec3) -> f32 {
    let (ab, av) = (b - a, v - a);
    let t = (av.dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
    ((av - t * ab).length_squared() + 1e-12).sqrt()
}

/// The geometric baseline: softmax(-beta · geodesic) per vertex; `geodesic` is [V, J]
/// row-major with `bones` = J.
pub fn baseline_weights(beta: f32, geodesic: &[f32], bones: usize) -> Vec<Vec<f32>> {
    geodesic
        .chunks(bones.max(1))
        .map(|row| {
            let mut w: Vec<f32> = row.iter().map(|g| -beta * g).collect();
            softmax(&mut w);
            w
        })
        .collect()
}

/// A vertex's four largest weights with their bones, renormalised to sum 1 (with fewer
/// than four bones the rest are bone 0 at weight 0).
pub fn top4(weights: &[f32]) -> ([u16; 4], [f32; 4]) {
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| weights[b].total_cmp(&weights[a]));
    let mut bones = [0u16; 4];
    let mut kept = [0.0f32; 4];
    for (slot, &b) in order.iter().take(4).enumerate() {
        bones[slot] = b as u16;
        kept[slot] = weights[b];
    }
    let total: f32 = kept.iter().sum();
    if total > 0.0 {
        kept.iter_mut().for_each(|w| *w /= total);
    }
    (bones, kept)
}
