//! The error type of the evaluation crate: inputs that cannot be compared (too few matched
//! poses, an empty surface, a nonsensical setting), each said in words a user can act on.

/// Result with [`EvalError`].
pub type Result<T, E = EvalError> = std::result::Result<T, E>;

/// Why an evaluation could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Too few estimated poses have a ground-truth pose at the same time.
    #[error(
        "only {matched} of {estimated} estimated poses have a ground-truth pose within {max_difference_s} s \
         (at least {needed} needed): are both files timed in the same clock?"
    )]
    TooFewMatches {
        /// Estimated poses with a ground-truth partner.
        matched: usize,
        /// Estimated poses in all.
        estimated: usize,
        /// Matches needed.
        needed: usize,
        /// The association tolerance used.
        max_difference_s: f64,
    },
    /// A mesh without any surface or point to measure against.
    #[error("the {0} mesh has no vertices")]
    EmptyMesh(&'static str),
    /// A setting out of its valid range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}
