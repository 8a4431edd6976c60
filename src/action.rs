//! The five actions that drive the avatar, key scripts ("30I 60W") and held-key state.
//! Action ids are the model's: 0 Idle, 1 Forward (W), 2 Backward (S), 3 Left (A), 4 Right (D).

use std::fmt;

#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
pub enum Action {
    #[default]
    Idle = 0,
    Forward = 1,
    Backward = 2,
    Left = 3,
    Right = 4,
}

impl Action {
    pub const ALL: [Action; 5] = [
        Action::Idle,
        Action::Forward,
        Action::Backward,
        Action::Left,
        Action::Right,
    ];

    pub fn id(self) -> u32 {
        self as u32
    }

    /// The action with model id `id` (Idle for an unknown id).
    pub fn from_id(id: u32) -> Action {
        Self::ALL.get(id as usize).copied().unwrap_or_default()
    }

    /// The key-script letter: I, W, S, A, D.
    pub fn letter(self) -> char {
        match self {
            Action::Idle => 'I',
            Action::Forward => 'W',
            Action::Backward => 'S',
            Action::Left => 'A',
            Action::Right => 'D',
        }
    }

    pub fn from_letter(c: char) -> Option<Action> {
        Self::ALL
            .into_iter()
            .find(|a| a.letter() == c.to_ascii_uppercase())
    }

    /// The keys move along fixed world directions (src/avatar/locomotion.rs: W +Z, A +X,
    /// S -Z, D -X): a movement key's direction as quarter turns about +Y from W's, the
    /// way the trainer's `dataset.quarter_turn` turns (+Z to +X); None for Idle.
    pub fn quarter(self) -> Option<u32> {
        match self {
            Action::Idle => None,
            Action::Forward => Some(0),
            Action::Left => Some(1),
            Action::Backward => Some(2),
            Action::Right => Some(3),
        }
    }

    /// The action of a frame turned `quarters` quarter turns about +Y (the trainer's
    /// `dataset.quarter_turn_action`): one turn takes W to A, A to S, S to D, D to W;
    /// Idle stays Idle.
    pub fn turned(self, quarters: u32) -> Action {
        const BY_QUARTER: [Action; 4] = [
            Action::Forward,
            Action::Left,
            Action::Backward,
            Action::Right,
        ];
        match self.quarter() {
            None => self,
            Some(q) => BY_QUARTER[((q + quarters) % 4) as usize],
        }
    }
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self, f)
    }
}

/// The most frames a key script may ask for: 1,000,000 (over 9 hours at 30 fps).
pub const MAX_SCRIPT_FRAMES: u64 = 1_000_000;

/// A scripted session: one action per frame, kept as runs (`count` frames of `action`),
/// so a long script costs no memory.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct KeyScript {
    /// Each run's action and the frame after it ends (increasing).
    runs: Vec<(Action, usize)>,
}

#[derive(Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "key script token {index} ('{token}'): {problem}; expected <count><key> with keys W A S D I, e.g. \"30I 60W\""
)]
pub struct ScriptError {
    pub index: usize,
    pub token: String,
    pub problem: &'static str,
}

impl KeyScript {
    /// Parses space-separated `<count><key>` tokens, e.g. `"60W 60S 60A 20I"`.
    /// At most [`MAX_SCRIPT_FRAMES`] frames in all.
    pub fn parse(text: &str) -> Result<Self, ScriptError> {
        let mut runs = Vec::new();
        let mut total: u64 = 0;
        for (index, token) in text.split_whitespace().enumerate() {
            let err = |problem| ScriptError {
                index: index + 1,
                token: token.into(),
                problem,
            };
            let key = token.chars().last().ok_or_else(|| err("empty"))?;
            let action = Action::from_letter(key).ok_or_else(|| err("unknown key"))?;
            let digits = &token[..token.len() - key.len_utf8()];
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return Err(err("the count is not a whole number"));
            }
            let count: u64 = digits.parse().unwrap_or(u64::MAX);
            if count == 0 {
                return Err(err("the count must be at least 1"));
            }
            total = total.saturating_add(count);
            if total > MAX_SCRIPT_FRAMES {
                return Err(err("the script asks for more than 1,000,000 frames"));
            }
            runs.push((action, total as usize));
        }
        if runs.is_empty() {
            return Err(ScriptError {
                index: 0,
                token: String::new(),
                problem: "the script is empty",
            });
        }
        Ok(Self { runs })
    }

    pub fn len(&self) -> usize {
        self.runs.last().map_or(0, |&(_, end)| end)
    }

    pub fn is_empty(&self) -> bool {
        self.runs.is_empty()
    }

    /// The action of frame `frame`; Idle after the script ends.
    pub fn action_at(&self, frame: usize) -> Action {
        let run = self.runs.partition_point(|&(_, end)| end <= frame);
        self.runs
            .get(run)
            .map_or(Action::Idle, |&(action, _)| action)
    }
}

/// Movement keys currently held; the most recently pressed one that is still held wins,
/// and no key held means Idle.
#[derive(Clone, Debug, Default)]
pub struct HeldKeys {
    order: Vec<Action>,
}

impl HeldKeys {
    pub fn press(&mut self, action: Action) {
        self.release(action);
        self.order.push(action);
    }

    pub fn release(&mut self, action: Action) {
        self.order.retain(|&a| a != action);
    }

    pub fn clear(&mut self) {
        self.order.clear();
    }

    pub fn current(&self) -> Action {
        self.order.last().copied().unwrap_or(Action::Idle)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_paper_trajectory() {
        let script = KeyScript::parse("60W 60S 60A 20I").unwrap();
        assert_eq!(script.len(), 200);
        assert_eq!(script.action_at(0), Action::Forward);
        assert_eq!(script.action_at(59), Action::Forward);
        assert_eq!(script.action_at(60), Action::Backward);
        assert_eq!(script.action_at(120), Action::Left);
        assert_eq!(script.action_at(199), Action::Idle);
        assert_eq!(script.action_at(10_000), Action::Idle);
    }

    #[test]
    fn lowercase_and_extra_spaces_are_fine() {
        let script = KeyScript::parse("  2d   1w ").unwrap();
        assert_eq!(
            (0..3).map(|i| script.action_at(i)).collect::<Vec<_>>(),
            [Action::Right, Action::Right, Action::Forward]
        );
    }

    #[test]
    fn bad_scripts_name_the_token() {
        let e = KeyScript::parse("30W 10X").unwrap_err();
        assert_eq!(
            (e.index, e.token.as_str(), e.problem),
            (2, "10X", "unknown key")
        );
        assert_eq!(
            KeyScript::parse("W").unwrap_err().problem,
            "the count is not a whole number"
        );
        assert_eq!(
            KeyScript::parse("0W").unwrap_err().problem,
            "the count must be at least 1"
        );
        assert_eq!(
            KeyScript::parse(" ").unwrap_err().problem,
            "the script is empty"
        );
        assert!(KeyScript::parse("-3W").is_err());
        assert!(KeyScript::parse("+3W").is_err());
        for huge in [
            "99999999999999W",
            "3000000000W",
            "999999999999999999999999W",
        ] {
            assert_eq!(
                KeyScript::parse(huge).unwrap_err().problem,
                "the script asks for more than 1,000,000 frames"
            );
        }
        assert!(KeyScript::parse("600000W 400001S").is_err());
        assert_eq!(
            KeyScript::parse("600000W 400000S").unwrap().len(),
            1_000_000
        );
        assert!(KeyScript::parse("3é").is_err());
        assert!(e.to_string().contains("'10X'"));
    }

    #[test]
    fn letters_round_trip_and_ids_are_the_models() {
        for a in Action::ALL {
            assert_eq!(Action::from_letter(a.letter()), Some(a));
        }
        assert_eq!(Action::ALL.map(Action::id), [0, 1, 2, 3, 4]);
    }

    #[test]
    fn quarter_turns_move_the_keys_as_the_trainer_does() {
        // dataset.QUARTER_TURN_ACTION = (0, 3, 4, 2, 1): one turn takes ids 1..4 to 3, 4, 2, 1.
        let once = Action::ALL.map(|a| a.turned(1).id());
        assert_eq!(once, [0, 3, 4, 2, 1]);
        for a in Action::ALL {
            assert_eq!(a.turned(4), a);
            assert_eq!(a.turned(3).turned(1), a);
            // Turning a key back by its own quarter gives W.
            if let Some(q) = a.quarter() {
                assert_eq!(a.turned(4 - q), Action::Forward);
            }
        }
        assert_eq!(Action::Idle.quarter(), None);
    }

    #[test]
    fn latest_held_key_wins_and_release_falls_back() {
        let mut keys = HeldKeys::default();
        assert_eq!(keys.current(), Action::Idle);
        keys.press(Action::Forward);
        keys.press(Action::Left);
        assert_eq!(keys.current(), Action::Left);
        keys.press(Action::Forward); // pressed again: back on top
        assert_eq!(keys.current(), Action::Forward);
        keys.release(Action::Forward);
        assert_eq!(keys.current(), Action::Left);
        keys.release(Action::Left);
        assert_eq!(keys.current(), Action::Idle);
    }
}
