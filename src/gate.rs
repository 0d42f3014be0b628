//! `[[gate]]`: the accuracy gates of a scenario, as written (their evaluation against a run's
//! metrics is in [`crate::ground_truth`]).

/// Up to six of `names` most like `metric` (in its family, the longest shared prefix first), for
/// errors about a metric that does not exist.
pub fn similar<'a>(names: &'a [String], metric: &str) -> Vec<&'a String> {
    let family = metric.split('.').next().unwrap_or("");
    let shared = |n: &str| {
        n.chars()
            .zip(metric.chars())
            .take_while(|(a, b)| a == b)
            .count()
    };
    let mut close: Vec<&String> = names
        .iter()
        .filter(|n| n.split('.').next() == Some(family))
        .collect();
    close.sort_by_key(|n| std::cmp::Reverse(shared(n)));
    close.truncate(6);
    close
}

/// A comparison of a gate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
pub enum Comparison {
    #[serde(rename = "<")]
    Less,
    #[serde(rename = "<=")]
    LessOrEqual,
    #[serde(rename = ">")]
    Greater,
    #[serde(rename = ">=")]
    GreaterOrEqual,
}

impl Comparison {
    pub fn symbol(self) -> &'static str {
        match self {
            Comparison::Less => "<",
            Comparison::LessOrEqual => "<=",
            Comparison::Greater => ">",
            Comparison::GreaterOrEqual => ">=",
        }
    }

    pub fn holds(self, v: f64, t: f64) -> bool {
        match self {
            Comparison::Less => v < t,
            Comparison::LessOrEqual => v <= t,
            Comparison::Greater => v > t,
            Comparison::GreaterOrEqual => v >= t,
        }
    }
}

/// `[[gate]]`: the run passes only if `metric op value` holds, or with `than`, `metric op
/// than + value` (value 0 unless given): a gate that ranks one metric against another of the
/// same run, e.g. one method's map against another's. With `scenario`, `metric op (the same
/// metric of that scenario's run) + value`: a gate of a suite, which ranks this scenario
/// against a baseline's run with the same seed (a run alone does not check it).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Gate {
    pub metric: String,
    pub op: Comparison,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub than: Option<String>,
    /// The scenario (its file's stem, in the same suite) whose run this one is ranked against.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scenario: Option<String>,
}
