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
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self, f)
    }
}

/// A scripted session: one action per frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct KeyScript {
    actions: Vec<Action>,
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
    pub fn parse(text: &str) -> Result<Self, ScriptError> {
        let mut actions = Vec::new();
        for (index, token) in text.split_whitespace().enumerate() {
            let err = |problem| ScriptError {
                index: index + 1,
                token: token.into(),
                problem,
            };
            let key = token.chars().last().ok_or_else(|| err("empty"))?;
            let action = Action::from_letter(key).ok_or_else(|| err("unknown key"))?;
            let count: usize = token[..token.len() - key.len_utf8()]
                .parse()
                .map_err(|_| err("the count is not a whole number"))?;
            if count == 0 {
                return Err(err("the count must be at least 1"));
            }
            actions.extend(std::iter::repeat_n(action, count));
        }
        if actions.is_empty() {
            return Err(ScriptError {
                index: 0,
                token: text.into(),
                problem: "the script is empty",
            });
        }
        Ok(Self { actions })
    }

    pub fn len(&self) -> usize {
        self.actions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }

    /// The action of frame `frame`; Idle after the script ends.
    pub fn action_at(&self, frame: usize) -> Action {
        self.actions.get(frame).copied().unwrap_or(Action::Idle)
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
