//! Skeleton-tree tokenization (UniRig): joint coordinates in the unit cube quantised to
//! 256 bins (decoded at the bin centre), special tokens, template parts and depth-first
//! linear chains. One sequence reads
//!
//! `bos class [template_body xyz×20 [template_hands xyz×38]] chains… eos`
//!
//! where a chain is `(branch|spring) parent_xyz joint_xyz…`, except that a non-humanoid
//! skeleton opens with its root chain's joints directly. Chains come from a depth-first
//! walk whose children are visited by their own position (z, then x, then y); a chain
//! continues while each joint is the previous one's child with the same spring flag.
//! Decoding attaches each chain to the earlier joint nearest its parent coordinates.
//! [`TokenDecoder`] is also the grammar: it says which tokens may come next.

use glam::Vec3;

use super::skeleton::{BODY, Class, Skeleton, template_joints};

pub const BINS: u32 = 256;
pub const BOS: u32 = 256;
pub const EOS: u32 = 257;
pub const BRANCH: u32 = 258;
pub const SPRING: u32 = 259;
pub const CLASS_HUMANOID: u32 = 260;
pub const CLASS_QUADRUPED: u32 = 261;
pub const CLASS_OTHER: u32 = 262;
pub const TEMPLATE_BODY: u32 = 263;
pub const TEMPLATE_HANDS: u32 = 264;
pub const VOCAB: usize = 265;
/// Longest skeleton a sequence may describe (decoding stops here).
pub const MAX_JOINTS: usize = 160;

/// The bin of a unit-cube coordinate (values outside [-1, 1] clamp to the end bins).
pub fn quantise(x: f32) -> u32 {
    (((x + 1.0) * 0.5 * BINS as f32).floor() as i64).clamp(0, BINS as i64 - 1) as u32
}

/// The centre of a bin, back in [-1, 1].
pub fn dequantise(bin: u32) -> f32 {
    (bin as f32 + 0.5) / BINS as f32 * 2.0 - 1.0
}

fn quantise3(p: Vec3) -> [u32; 3] {
    [quantise(p.x), quantise(p.y), quantise(p.z)]
}

fn dequantise3(q: [u32; 3]) -> Vec3 {
    Vec3::new(dequantise(q[0]), dequantise(q[1]), dequantise(q[2]))
}

/// The skeleton as decoded from its own tokens: every joint at its bin centre.
pub fn quantised(skeleton: &Skeleton) -> Skeleton {
    skeleton.map_joints(|p| dequantise3(quantise3(p)))
}

pub fn class_token(class: Class) -> u32 {
    match class {
        Class::Humanoid => CLASS_HUMANOID,
        Class::Quadruped => CLASS_QUADRUPED,
        Class::Other => CLASS_OTHER,
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TokenError {
    #[error("a humanoid skeleton needs the template joint {0}")]
    MissingTemplateJoint(String),
    #[error("template joint {0} does not hang from the template's parent {1}")]
    TemplateParent(String, String),
    #[error("joint {0} has no parent, but only the first joint may be a root")]
    ExtraRoot(usize),
    #[error("the skeleton has {0} joints, more than the {MAX_JOINTS} a sequence may hold")]
    TooMany(usize),
    #[error("joints are not in parent-before-child order")]
    Unordered,
    #[error("token {token} is not allowed at position {position}")]
    Unexpected { token: u32, position: usize },
    #[error("the sequence ends before eos")]
    Unfinished,
}

/// Encodes a skeleton whose joints are in the unit cube.
pub fn encode(skeleton: &Skeleton) -> Result<Vec<u32>, TokenError> {
    if skeleton.len() > MAX_JOINTS {
        return Err(TokenError::TooMany(skeleton.len()));
    }
    if !skeleton.is_ordered() {
        return Err(TokenError::Unordered);
    }
    let q: Vec<[u32; 3]> = skeleton.joints.iter().map(|&p| quantise3(p)).collect();
    let mut tokens = vec![BOS, class_token(skeleton.class)];
    let mut emitted = vec![false; skeleton.len()];
    if skeleton.class == Class::Humanoid {
        let find = |name: &str| skeleton.names.iter().position(|n| n == name);
        let hands = template_joints(true)[BODY.len()..]
            .iter()
            .all(|(name, _)| find(name).is_some());
        for (part, (name, parent)) in template_joints(hands).iter().enumerate() {
            if part == 0 {
                tokens.push(TEMPLATE_BODY);
            } else if part == BODY.len() {
                tokens.push(TEMPLATE_HANDS);
            }
            let j = find(name).ok_or_else(|| TokenError::MissingTemplateJoint(name.clone()))?;
            let parent_index = parent.as_deref().and_then(find);
            if skeleton.parents[j] != parent_index {
                return Err(TokenError::TemplateParent(
                    name.clone(),
                    parent.clone().unwrap_or_else(|| "(none)".into()),
                ));
            }
            tokens.extend(q[j]);
            emitted[j] = true;
        }
    }
    let mut previous: Option<usize> = None;
    for j in depth_first(skeleton, &q) {
        if emitted[j] {
            previous = None;
            continue;
        }
        let parent = skeleton.parents[j];
        let continues = parent.is_some()
            && parent == previous
            && previous.is_some_and(|p| skeleton.spring[p] == skeleton.spring[j]);
        if !continues {
            match parent {
                Some(p) => {
                    tokens.push(if skeleton.spring[j] { SPRING } else { BRANCH });
                    tokens.extend(q[p]);
                }
                None if tokens.len() == 2 => {}
                None => return Err(TokenError::ExtraRoot(j)),
            }
        }
        tokens.extend(q[j]);
        emitted[j] = true;
        previous = Some(j);
    }
    tokens.push(EOS);
    Ok(tokens)
}

/// Joints in depth-first order from the roots, children by their bins (z, x, y).
fn depth_first(skeleton: &Skeleton, q: &[[u32; 3]]) -> Vec<usize> {
    let key = |j: usize| (q[j][2], q[j][0], q[j][1], j);
    let mut roots: Vec<usize> = (0..skeleton.len())
        .filter(|&j| skeleton.parents[j].is_none())
        .collect();
    roots.sort_by_key(|&j| key(j));
    let mut order = Vec::with_capacity(skeleton.len());
    let mut stack: Vec<usize> = roots.into_iter().rev().collect();
    while let Some(j) = stack.pop() {
        order.push(j);
        let mut children: Vec<usize> = skeleton.children(j).collect();
        children.sort_by_key(|&c| key(c));
        stack.extend(children.into_iter().rev());
    }
    order
}

/// The naive encoding's length: every bone as its two end points (6 tokens), with bos,
/// class and eos, for the reduction the chains buy.
pub fn naive_length(skeleton: &Skeleton) -> usize {
    3 + 6 * skeleton.parents.iter().filter(|p| p.is_some()).count()
}

/// Where the decoder is in the grammar.
#[derive(Clone, Debug, PartialEq)]
enum State {
    Start,
    Class,
    /// Humanoid: template_body must come.
    Body,
    /// Inside a template part: joints still to read.
    Template {
        left: usize,
    },
    /// A non-humanoid's first joint.
    Root,
    /// After a whole joint of a chain (or a template part).
    Boundary,
    /// Reading the parent coordinates after branch/spring.
    Parent {
        spring: bool,
    },
    /// Reading the first joint of a chain after its parent.
    FirstJoint,
    Done,
}

/// Incremental decoder and grammar: feed tokens one by one; [`TokenDecoder::allowed`] says
/// which may come next.
#[derive(Clone, Debug)]
pub struct TokenDecoder {
    state: State,
    class: Class,
    bins: Vec<u32>,
    joints: Vec<[u32; 3]>,
    parents: Vec<Option<usize>>,
    names: Vec<String>,
    spring: Vec<bool>,
    template: Vec<(String, Option<String>)>,
    /// The chain being read: its spring flag and last joint.
    chain_spring: bool,
    chain_last: Option<usize>,
    branch_parent: Option<usize>,
    position: usize,
    chains: usize,
}

impl Default for TokenDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl TokenDecoder {
    pub fn new() -> Self {
        Self {
            state: State::Start,
            class: Class::Other,
            bins: Vec::new(),
            joints: Vec::new(),
            parents: Vec::new(),
            names: Vec::new(),
            spring: Vec::new(),
            template: template_joints(true),
            chain_spring: false,
            chain_last: None,
            branch_parent: None,
            position: 0,
            chains: 0,
        }
    }

    pub fn is_done(&self) -> bool {
        self.state == State::Done
    }

    /// Which tokens may come next (all false once eos was read).
    pub fn allowed(&self) -> [bool; VOCAB] {
        let mut ok = [false; VOCAB];
        let coords =
            |ok: &mut [bool; VOCAB]| ok[..BINS as usize].iter_mut().for_each(|b| *b = true);
        match &self.state {
            State::Start => ok[BOS as usize] = true,
            State::Class => {
                for class in Class::ALL {
                    ok[class_token(class) as usize] = true;
                }
            }
            State::Body => ok[TEMPLATE_BODY as usize] = true,
            State::Template { .. } | State::Root | State::FirstJoint => coords(&mut ok),
            State::Boundary if !self.bins.is_empty() => coords(&mut ok),
            State::Boundary => {
                let full = self.joints.len() >= MAX_JOINTS;
                if !full {
                    if self.chain_last.is_some() {
                        coords(&mut ok);
                    }
                    ok[BRANCH as usize] = true;
                    ok[SPRING as usize] = true;
                }
                if self.class == Class::Humanoid && self.joints.len() == BODY.len() && !full {
                    ok[TEMPLATE_HANDS as usize] = true;
                }
                ok[EOS as usize] = true;
            }
            State::Parent { .. } => {
                // Only coordinates of an existing joint, matching the bins read so far.
                for q in &self.joints {
                    if q[..self.bins.len()] == self.bins[..] {
                        ok[q[self.bins.len()] as usize] = true;
                    }
                }
            }
            State::Done => {}
        }
        ok
    }

    /// Reads one token; a token the grammar does not allow is an error.
    pub fn push(&mut self, token: u32) -> Result<(), TokenError> {
        if !self.allowed().get(token as usize).copied().unwrap_or(false) {
            return Err(TokenError::Unexpected {
                token,
                position: self.position,
            });
        }
        self.position += 1;
        match self.state.clone() {
            State::Start => self.state = State::Class,
            State::Class => {
                self.class = match token {
                    CLASS_HUMANOID => Class::Humanoid,
                    CLASS_QUADRUPED => Class::Quadruped,
                    _ => Class::Other,
                };
                self.state = if self.class == Class::Humanoid {
                    State::Body
                } else {
                    State::Root
                };
            }
            State::Body => {
                self.state = State::Template { left: BODY.len() };
            }
            State::Template { left } => {
                if let Some(q) = self.take_joint(token) {
                    let (name, parent) = self.template[self.joints.len()].clone();
                    let parent = parent.and_then(|p| self.names.iter().position(|n| *n == p));
                    self.add_joint(q, parent, name, false);
                    self.chain_last = None;
                    self.state = if left > 1 {
                        State::Template { left: left - 1 }
                    } else {
                        State::Boundary
                    };
                }
            }
            State::Root => {
                if let Some(q) = self.take_joint(token) {
                    self.chains = 1;
                    let name = self.free_name(false);
                    self.add_joint(q, None, name, false);
                    self.chain_spring = false;
                    self.state = State::Boundary;
                }
            }
            State::Boundary if !self.bins.is_empty() || token < BINS => {
                if let Some(q) = self.take_joint(token) {
                    let name = self.free_name(self.chain_spring);
                    self.add_joint(q, self.chain_last, name, self.chain_spring);
                }
            }
            State::Boundary => match token {
                BRANCH | SPRING => {
                    self.state = State::Parent {
                        spring: token == SPRING,
                    }
                }
                TEMPLATE_HANDS => {
                    self.state = State::Template {
                        left: self.template.len() - BODY.len(),
                    }
                }
                _ => self.state = State::Done,
            },
            State::Parent { spring } => {
                if let Some(q) = self.take_joint(token) {
                    self.branch_parent = self.nearest(dequantise3(q));
                    self.chain_spring = spring;
                    self.chains += 1;
                    self.state = State::FirstJoint;
                }
            }
            State::FirstJoint => {
                if let Some(q) = self.take_joint(token) {
                    let name = self.free_name(self.chain_spring);
                    self.add_joint(q, self.branch_parent, name, self.chain_spring);
                    self.state = State::Boundary;
                }
            }
            State::Done => {}
        }
        Ok(())
    }

    /// Collects coordinate bins; returns a joint's three once complete.
    fn take_joint(&mut self, bin: u32) -> Option<[u32; 3]> {
        self.bins.push(bin);
        (self.bins.len() == 3).then(|| {
            let q = [self.bins[0], self.bins[1], self.bins[2]];
            self.bins.clear();
            q
        })
    }

    fn add_joint(&mut self, q: [u32; 3], parent: Option<usize>, name: String, spring: bool) {
        self.joints.push(q);
        self.parents.push(parent);
        self.names.push(name);
        self.spring.push(spring);
        self.chain_last = Some(self.joints.len() - 1);
    }

    fn free_name(&self, spring: bool) -> String {
        let kind = if spring { "Spring" } else { "Joint" };
        format!("{kind}{}_{}", self.chains, self.joints.len())
    }

    /// The earlier joint nearest `p` (the latest one on a tie).
    fn nearest(&self, p: Vec3) -> Option<usize> {
        let mut best: Option<(usize, f32)> = None;
        for (j, &q) in self.joints.iter().enumerate() {
            let d = dequantise3(q).distance_squared(p);
            if best.is_none_or(|(_, b)| d <= b) {
                best = Some((j, d));
            }
        }
        best.map(|(j, _)| j)
    }

    /// The skeleton read so far (joints at bin centres).
    pub fn skeleton(&self) -> Skeleton {
        Skeleton {
            class: self.class,
            joints: self.joints.iter().map(|&q| dequantise3(q)).collect(),
            parents: self.parents.clone(),
            names: self.names.clone(),
            spring: self.spring.clone(),
        }
    }
}

/// Decodes a whole sequence (bos … eos).
pub fn decode(tokens: &[u32]) -> Result<Skeleton, TokenError> {
    let mut decoder = TokenDecoder::new();
    for &t in tokens {
        decoder.push(t)?;
    }
    if !decoder.is_done() {
        return Err(TokenError::Unfinished);
    }
    Ok(decoder.skeleton())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// A random tree in the unit cube: each joint hangs from a random earlier one, at a
    /// distinct bin, some chains springs.
    fn random_tree(rng: &mut Rng, joints: usize) -> Skeleton {
        let mut skeleton = Skeleton {
            class: Class::Other,
            joints: Vec::new(),
            parents: Vec::new(),
            names: Vec::new(),
            spring: Vec::new(),
        };
        let mut used = std::collections::HashSet::new();
        while skeleton.len() < joints {
            let p = Vec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            );
            if !used.insert(quantise3(p)) {
                continue;
            }
            let j = skeleton.len();
            let parent = (j > 0).then(|| rng.below(j));
            let spring = parent.is_some_and(|p| p > 0 && (skeleton.spring[p] || rng.chance(0.2)));
            skeleton.joints.push(p);
            skeleton.parents.push(parent);
            skeleton.names.push(format!("j{j}"));
            skeleton.spring.push(spring);
        }
        skeleton
    }

    /// Same tree up to the order of joints and the free joints' names.
    fn assert_same_tree(a: &Skeleton, b: &Skeleton) {
        assert_eq!(a.class, b.class);
        assert_eq!(a.len(), b.len());
        let key = |s: &Skeleton, j: usize| {
            let parent = s.parents[j].map(|p| quantise3(s.joints[p]));
            (quantise3(s.joints[j]), parent, s.spring[j])
        };
        let mut ka: Vec<_> = (0..a.len()).map(|j| key(a, j)).collect();
        let mut kb: Vec<_> = (0..b.len()).map(|j| key(b, j)).collect();
        ka.sort();
        kb.sort();
        assert_eq!(ka, kb);
    }

    #[test]
    fn bins_have_known_centres() {
        assert_eq!(quantise(-1.0), 0);
        assert_eq!(quantise(1.0), 255);
        assert_eq!(quantise(0.0), 128);
        assert_eq!(quantise(-1e-6), 127);
        assert_eq!(dequantise(0), -1.0 + 1.0 / 256.0);
        assert_eq!(dequantise(255), 1.0 - 1.0 / 256.0);
        for bin in 0..BINS {
            assert_eq!(quantise(dequantise(bin)), bin);
        }
    }

    #[test]
    fn random_trees_round_trip_exactly() {
        let mut rng = Rng::new(3);
        for case in 0..200 {
            let tree = random_tree(&mut rng, 1 + case % 60);
            let tokens = encode(&tree).unwrap();
            let decoded = decode(&tokens).unwrap();
            assert_same_tree(&quantised(&tree), &decoded);
            // Decoding is a fixed point: the decoded tree encodes to the same tokens.
            assert_eq!(encode(&decoded).unwrap(), tokens);
        }
    }

    #[test]
    fn a_small_tree_has_the_documented_tokens() {
        // Root at the centre with two children: the one with the smaller z comes first
        // and continues the root chain; the other opens a branch from the root.
        let c = dequantise(128);
        let skeleton = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::splat(c), Vec3::new(c, c, 0.5), Vec3::new(c, c, -0.5)],
            parents: vec![None, Some(0), Some(0)],
            names: vec!["a".into(), "b".into(), "c".into()],
            spring: vec![false, false, true],
        };
        let tokens = encode(&skeleton).unwrap();
        assert_eq!(
            tokens,
            vec![
                BOS,
                CLASS_OTHER,
                128,
                128,
                128,
                SPRING,
                128,
                128,
                128,
                128,
                128,
                64,
                BRANCH,
                128,
                128,
                128,
                128,
                128,
                192,
                EOS
            ]
        );
        assert!(tokens.len() < naive_length(&skeleton) + 8);
    }

    #[test]
    fn the_grammar_admits_only_valid_continuations() {
        let mut d = TokenDecoder::new();
        assert!(d.push(EOS).is_err());
        d.push(BOS).unwrap();
        d.push(CLASS_HUMANOID).unwrap();
        // A humanoid must open with the body template.
        assert!(d.push(BRANCH).is_err());
        d.push(TEMPLATE_BODY).unwrap();
        for k in 0..BODY.len() * 3 {
            let allowed = d.allowed();
            assert!(!allowed[EOS as usize] && !allowed[BRANCH as usize]);
            d.push((k * 7 % 256) as u32).unwrap();
        }
        let allowed = d.allowed();
        assert!(allowed[TEMPLATE_HANDS as usize] && allowed[EOS as usize]);
        assert!(!allowed[5], "a template part is not a chain to continue");
        d.push(BRANCH).unwrap();
        // The parent's coordinates must be an existing joint's.
        let allowed = d.allowed();
        assert_eq!(allowed.iter().filter(|&&a| a).count(), {
            let mut xs: Vec<_> = (0..BODY.len()).map(|j| (j * 3 * 7) % 256).collect();
            xs.sort();
            xs.dedup();
            xs.len()
        });
        let skeleton = d.skeleton();
        assert_eq!(skeleton.names[16], "Foot.L");
        assert_eq!(skeleton.parents[16], Some(15));
    }

    #[test]
    fn decoding_stops_at_the_joint_limit() {
        let mut d = TokenDecoder::new();
        for t in [BOS, CLASS_OTHER] {
            d.push(t).unwrap();
        }
        for k in 0..MAX_JOINTS * 3 {
            d.push((k % 256) as u32).unwrap();
        }
        let allowed = d.allowed();
        assert_eq!(allowed.iter().filter(|&&a| a).count(), 1);
        assert!(allowed[EOS as usize]);
    }

    #[test]
    fn bad_trees_are_refused() {
        let mut rng = Rng::new(1);
        let mut forest = random_tree(&mut rng, 5);
        forest.parents[3] = None;
        assert_eq!(encode(&forest), Err(TokenError::ExtraRoot(3)));
        let mut humanoid = random_tree(&mut rng, 5);
        humanoid.class = Class::Humanoid;
        assert_eq!(
            encode(&humanoid),
            Err(TokenError::MissingTemplateJoint("Hips".into()))
        );
    }
}
