//! The discrete action set of the AI2THOR object-navigation task (paper Sec. 5.1).

/// Number of discrete actions (`|A|` in the paper).
pub const NUM_ACTIONS: usize = 6;

/// One navigation action, in the order the policy's actor head emits logits.
///
/// The order matches the reference implementation and the paper's action set
/// `A = {MoveAhead, RotateLeft, RotateRight, LookUp, LookDown, Done}`; index `i` of every
/// probability vector in this crate is the probability of `Action::ALL[i]`.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[repr(u8)]
pub enum Action {
    /// Move 0.25 m along the current heading; fails (agent stays) if the target cell is blocked.
    MoveAhead = 0,
    /// Turn 45 degrees to the left (counter-clockwise seen from above).
    RotateLeft = 1,
    /// Turn 45 degrees to the right.
    RotateRight = 2,
    /// Raise the camera by 30 degrees (from 30 down back to 0).
    LookUp = 3,
    /// Lower the camera by 30 degrees (from 0 to 30 down).
    LookDown = 4,
    /// Declare that the target is found; ends the episode.
    Done = 5,
}

impl Action {
    /// All actions in logit order.
    pub const ALL: [Action; NUM_ACTIONS] = [
        Action::MoveAhead,
        Action::RotateLeft,
        Action::RotateRight,
        Action::LookUp,
        Action::LookDown,
        Action::Done,
    ];

    /// Index of this action in a probability or logit vector.
    #[inline]
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The action at `index`, or `None` when `index >= NUM_ACTIONS`.
    #[inline]
    pub const fn from_index(index: usize) -> Option<Action> {
        if index < NUM_ACTIONS {
            Some(Action::ALL[index])
        } else {
            None
        }
    }

    /// The name used in AI2THOR and in the paper.
    pub const fn name(self) -> &'static str {
        match self {
            Action::MoveAhead => "MoveAhead",
            Action::RotateLeft => "RotateLeft",
            Action::RotateRight => "RotateRight",
            Action::LookUp => "LookUp",
            Action::LookDown => "LookDown",
            Action::Done => "Done",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_round_trip() {
        for (i, a) in Action::ALL.iter().enumerate() {
            assert_eq!(a.index(), i);
            assert_eq!(Action::from_index(i), Some(*a));
        }
        assert_eq!(Action::from_index(NUM_ACTIONS), None);
    }
}
