//! Shards: which views of the list one process renders, from `--shard K/N`, `--shards N` or
//! the scheduler's environment (Slurm job arrays, Kubernetes Indexed Jobs).

use crate::spelling::opt;
use std::fmt;

/// Shard `index` of `count` (0-based) holds the views whose position `i` in the view list
/// has `i % count == index`: deterministic, balanced, and independent of what exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// This shard's index, 0-based, < `count`.
    pub index: u32,
    /// Number of shards, >= 1.
    pub count: u32,
}

impl Shard {
    /// The one shard of one: every view.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Shard `index` of `count`; an error unless `count >= 1` and `index < count`.
    pub fn new(index: u32, count: u32) -> Result<Shard, String> {
        if count == 0 {
            return Err("shard count must be >= 1, got 0".into());
        }
        if index >= count {
            return Err(format!(
                "shard index must be < count (0-based), got {index}/{count}"
            ));
        }
        Ok(Shard { index, count })
    }

    /// Parse `K/N`.
    pub fn parse(s: &str) -> Result<Shard, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("expected K/N (0-based), got {s:?}"))?;
        let num = |t: &str| {
            t.trim()
                .parse::<u32>()
                .map_err(|_| format!("expected K/N with whole numbers, got {s:?}"))
        };
        Shard::new(num(k)?, num(n)?)
    }

    /// Whether the view at position `view_index` of the view list is in this shard.
    pub fn contains(&self, view_index: usize) -> bool {
        view_index % self.count as usize == self.index as usize
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-of-{}", self.index, self.count)
    }
}

/// The shard to render: `--shard K/N`; else with `--shards N` the index from
/// `JOB_COMPLETION_INDEX` (Kubernetes Indexed Job) or `SLURM_ARRAY_TASK_ID -
/// SLURM_ARRAY_TASK_MIN`; else from Slurm's array variables
/// (`SLURM_ARRAY_TASK_COUNT` shards); else the whole input.
pub fn resolve_shard(
    shard: Option<Shard>,
    shards: Option<u32>,
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<Shard, String> {
    let var = |name: &str| -> Result<Option<u32>, String> {
        match env(name) {
            None => Ok(None),
            Some(v) => v
                .trim()
                .parse::<u32>()
                .map(Some)
                .map_err(|_| format!("{name}: expected a whole number, got {v:?}")),
        }
    };
    let slurm_index = || -> Result<Option<u32>, String> {
        let Some(id) = var("SLURM_ARRAY_TASK_ID")? else {
            return Ok(None);
        };
        let min = var("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
        id.checked_sub(min).map(Some).ok_or_else(|| {
            format!("SLURM_ARRAY_TASK_ID ({id}) is below SLURM_ARRAY_TASK_MIN ({min})")
        })
    };
    match (shard, shards) {
        (Some(_), Some(_)) => Err(format!(
            "give {} K/N or {} N, not both",
            opt("shard"),
            opt("shards")
        )),
        (Some(s), None) => Ok(s),
        (None, Some(n)) => {
            let index = match var("JOB_COMPLETION_INDEX")? {
                Some(i) => i,
                None => slurm_index()?.ok_or_else(|| {
                    format!(
                        "{} N needs JOB_COMPLETION_INDEX (Kubernetes Indexed Job) or \
                         SLURM_ARRAY_TASK_ID in the environment; or give {} K/N",
                        opt("shards"),
                        opt("shard")
                    )
                })?,
            };
            Shard::new(index, n).map_err(|e| format!("{} {n}: {e}", opt("shards")))
        }
        (None, None) => match slurm_index()? {
            None => Ok(Shard::ALL),
            Some(index) => {
                let count = var("SLURM_ARRAY_TASK_COUNT")?
                    .ok_or("SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not")?;
                Shard::new(index, count).map_err(|e| format!("Slurm array: {e}"))
            }
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_partition() {
        assert_eq!(Shard::parse("2/7"), Ok(Shard { index: 2, count: 7 }));
        assert!(Shard::parse("7/7").unwrap_err().contains("must be < count"));
        assert!(Shard::parse("1/0").is_err());
        assert!(Shard::parse("a/2").is_err());
        for n in [1u32, 2, 7] {
            let mut hits = vec![0; 50];
            for k in 0..n {
                let s = Shard::new(k, n).unwrap();
                (0..50)
                    .filter(|&i| s.contains(i))
                    .for_each(|i| hits[i] += 1);
            }
            assert!(hits.iter().all(|&h| h == 1), "N = {n}: {hits:?}");
        }
    }

    #[test]
    fn shard_from_environment() {
        let env = |vars: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                vars.iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| v.to_string())
            }
        };
        let none = env(&[]);
        assert_eq!(resolve_shard(None, None, &none), Ok(Shard::ALL));
        let slurm = env(&[
            ("SLURM_ARRAY_TASK_ID", "12"),
            ("SLURM_ARRAY_TASK_MIN", "10"),
            ("SLURM_ARRAY_TASK_COUNT", "4"),
        ]);
        assert_eq!(
            resolve_shard(None, None, &slurm),
            Ok(Shard::new(2, 4).unwrap())
        );
        let k8s = env(&[("JOB_COMPLETION_INDEX", "3")]);
        assert_eq!(
            resolve_shard(None, Some(5), &k8s),
            Ok(Shard::new(3, 5).unwrap())
        );
        assert!(
            resolve_shard(None, Some(3), &k8s)
                .unwrap_err()
                .contains("must be < count")
        );
        assert!(
            resolve_shard(None, Some(3), &none)
                .unwrap_err()
                .contains("JOB_COMPLETION_INDEX")
        );
        let explicit = Some(Shard::new(1, 2).unwrap());
        assert_eq!(
            resolve_shard(explicit, None, &slurm),
            explicit.ok_or(String::new())
        );
        assert!(resolve_shard(explicit, Some(2), &none).is_err());
        let bad = env(&[("SLURM_ARRAY_TASK_ID", "x")]);
        assert!(
            resolve_shard(None, None, &bad)
                .unwrap_err()
                .contains("SLURM_ARRAY_TASK_ID")
        );
    }
}
