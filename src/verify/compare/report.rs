//! The report and its wording: the printed labels, the explanations, the verdict lines.

use super::*;

/// The result of [`compare`]: counts, error statistics, notes. `Serialize` for `--json`,
/// `Display` for a person.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    /// Image width in pixels (both images have the same size).
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// `width × height`: the denominator of the mismatch fractions.
    pub pixels: usize,
    /// How pixel identity was decided (what "same" means below).
    pub identity: Identity,
    /// Whether per-pixel float32 conditioning bounds were applied.
    pub conditioned: bool,
    /// Channels present in both images with compatible sample types (compared).
    pub channels: Vec<String>,
    /// Channels present in both images but not compared because their sample types differ
    /// (u32 in one, float32 in the other; `shape_id` and `part` never land here: they are
    /// compared as ids whatever their type).
    pub type_clashes: Vec<String>,
    /// Channels only one image has (not compared).
    pub only_in_a: Vec<String>,
    /// Channels only B has (not compared).
    pub only_in_b: Vec<String>,
    /// Pixels where A hits (non-zero `shape_id`, or hit by `distance`/`depth` > 0 under
    /// [`Identity::HitMiss`]).
    pub hits_a: usize,
    /// Pixels where B hits, by the same rule.
    pub hits_b: usize,
    /// Pixels where both hit the same part of the same cylinder (the same cylinder, or just
    /// both hit, under a coarser [`Identity`]): the statistics' population.
    pub same: usize,
    /// Pixels of different cylinders or hit vs miss.
    pub silhouette_mismatches: usize,
    /// Those of `silhouette_mismatches` next to a cylinder boundary in either image (the kind
    /// that may be allowed).
    pub silhouette_on_boundary: usize,
    /// Silhouette mismatches over all pixels (what `max_mismatch_fraction` bounds).
    pub silhouette_fraction: f64,
    /// Pixels of the same cylinder but another part.
    pub seams: usize,
    /// Those of `seams` next to a (cylinder, part) boundary in either image (the
    /// kind that may be allowed).
    pub seams_on_boundary: usize,
    /// Seam mismatches over all pixels (what `max_seam_fraction` bounds).
    pub seam_fraction: f64,
    /// Up to 10 seam mismatches on a part boundary, `[x, y]`.
    pub seam_examples: Vec<[usize; 2]>,
    /// Mismatches of either kind, silhouette and seam, away from any boundary (always a
    /// failure).
    pub mismatches_interior: usize,
    /// Up to 10 interior mismatches, `[x, y]`.
    pub interior_examples: Vec<[usize; 2]>,
    /// Relative distance error `|a - b| / max(|a|, |b|)` (needs `distance` in both).
    pub rel_distance: Option<Metric>,
    /// Relative planar-depth error, same formula (needs `depth` in both).
    pub rel_depth: Option<Metric>,
    /// Normal angle error in degrees (needs `normal` in both).
    pub normal_deg: Option<Metric>,
    /// `|Δposition|` in world units.
    pub position_abs: Option<Stat>,
    /// `|Δposition| / distance` (needs `distance` in both).
    pub position_rel: Option<Stat>,
    /// On pixels both images hit on the same cylinder's side (`part` 1 or 2): the larger of
    /// `|Δu|` modulo 1 (a turn) and `|Δv|` (needs `uv` in both; absent from `--json`
    /// otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uv_side: Option<Stat>,
    /// Non-finite samples in A's compared float channels (any is a failure).
    pub non_finite_a: usize,
    /// Non-finite samples in B's compared float channels (any is a failure).
    pub non_finite_b: usize,
    /// What the comparison could not do or check (missing identity channels, type clashes,
    /// no error channel), one sentence each.
    pub notes: Vec<String>,
}

impl Report {
    /// One line per metric that has pixels above its flat bound which their float32
    /// conditioning bound explains (what the grazing rule accepted; empty without
    /// conditioning or when the flat bounds hold everywhere).
    pub fn explained_lines(&self, tol: &Tolerances) -> Vec<String> {
        let mut out = Vec::new();
        for (name, m, flat) in [
            ("relative distance", &self.rel_distance, tol.rel_distance),
            ("relative depth", &self.rel_depth, tol.rel_depth),
            ("normal angle (deg)", &self.normal_deg, tol.normal_deg),
        ] {
            let Some(m) = m else { continue };
            if let (n, Some((e, at, bound))) = m.explained_above(flat) {
                let more = if n == EXPLAINED_KEPT { "at least " } else { "" };
                out.push(format!(
                    "{name}: {more}{n} px above {flat:.3e}, each within its float32 conditioning bound (largest {e:.3e} at {at:?}, bound {bound:.3e})"
                ));
            }
        }
        out
    }

    /// Whether every tolerance holds.
    pub fn passes(&self, tol: &Tolerances) -> bool {
        self.failures(tol).is_empty()
    }

    /// One line per broken tolerance (empty when the comparison passes): which bound, by
    /// how much, and where.
    pub fn failures(&self, tol: &Tolerances) -> Vec<String> {
        let mut out = Vec::new();
        if self.silhouette_fraction > tol.max_mismatch_fraction {
            out.push(format!(
                "silhouette mismatch fraction {:.3e} ({} px) > {:.3e}",
                self.silhouette_fraction, self.silhouette_mismatches, tol.max_mismatch_fraction
            ));
        }
        if self.seam_fraction > tol.max_seam_fraction {
            out.push(format!(
                "seam mismatch fraction {:.3e} ({} px) > {:.3e}",
                self.seam_fraction, self.seams, tol.max_seam_fraction
            ));
        }
        if self.mismatches_interior > 0 {
            out.push(format!(
                "{} mismatches off silhouettes and seams, e.g. at {:?}",
                self.mismatches_interior, self.interior_examples
            ));
        }
        let beyond = if self.conditioned {
            " (beyond its float32 conditioning bound)"
        } else {
            ""
        };
        let mut check = |name: &str, m: &Option<Metric>, limit: f64| {
            if let Some(m) = m
                && m.checked().max > limit
            {
                let s = m.checked();
                out.push(format!(
                    "{name} max {:.3e} > {limit:.3e} at {:?}{beyond}",
                    s.max,
                    s.worst_pixel.unwrap_or_default()
                ));
            }
        };
        check(
            "relative distance error",
            &self.rel_distance,
            tol.rel_distance,
        );
        check("relative depth error", &self.rel_depth, tol.rel_depth);
        check("normal angle error (deg)", &self.normal_deg, tol.normal_deg);
        if self.non_finite_a + self.non_finite_b > 0 {
            out.push(format!(
                "non-finite samples: A {}, B {}",
                self.non_finite_a, self.non_finite_b
            ));
        }
        out
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let identity = match self.identity {
            Identity::ShapeIdPart => "by shape_id and part",
            Identity::ShapeId => "by shape_id",
            Identity::HitMiss => "by hit/miss only",
        };
        writeln!(
            f,
            "{}x{} pixels, identity {identity}; compared: {}",
            self.width,
            self.height,
            self.channels.join(" ")
        )?;
        if !self.only_in_a.is_empty() || !self.only_in_b.is_empty() {
            writeln!(
                f,
                "not compared: only in A [{}], only in B [{}]",
                self.only_in_a.join(" "),
                self.only_in_b.join(" ")
            )?;
        }
        let same = match self.identity {
            Identity::ShapeIdPart => "same cylinder and part",
            Identity::ShapeId => "same cylinder",
            Identity::HitMiss => "both hit",
        };
        writeln!(
            f,
            "hits: A {}, B {}, {same} {}",
            self.hits_a, self.hits_b, self.same
        )?;
        writeln!(
            f,
            "mismatches: {} ({:.4}%) silhouette, {} ({:.4}%) seam; {} of them interior",
            self.silhouette_mismatches,
            100.0 * self.silhouette_fraction,
            self.seams,
            100.0 * self.seam_fraction,
            self.mismatches_interior
        )?;
        writeln!(
            f,
            "{:<22} {:>11} {:>11} {:>11}  worst [x, y]",
            "error", "median", "p99", "max"
        )?;
        let row = |f: &mut fmt::Formatter<'_>, name: &str, s: &Stat| {
            let at = s
                .worst_pixel
                .map_or("-".to_string(), |p| format!("[{}, {}]", p[0], p[1]));
            writeln!(
                f,
                "{name:<22} {:>11.3e} {:>11.3e} {:>11.3e}  {at}",
                s.median, s.p99, s.max
            )
        };
        for (name, m) in [
            ("relative distance", &self.rel_distance),
            ("relative depth", &self.rel_depth),
            ("normal angle (deg)", &self.normal_deg),
        ] {
            if let Some(m) = m {
                row(f, name, &m.all)?;
            }
        }
        for (name, s) in [
            ("position (abs)", &self.position_abs),
            ("position / distance", &self.position_rel),
            ("uv (side, u mod 1)", &self.uv_side),
        ] {
            if let Some(s) = s {
                row(f, name, s)?;
            }
        }
        if self.conditioned {
            writeln!(
                f,
                "float32 conditioning bounds applied (ray error {CONDITIONING_ULPS} ulps)"
            )?;
        }
        write!(
            f,
            "non-finite samples: A {}, B {}",
            self.non_finite_a, self.non_finite_b
        )?;
        for n in &self.notes {
            write!(f, "\nnote: {n}")?;
        }
        Ok(())
    }
}

/// The tolerance line of a text report.
pub fn tolerance_line(t: &Tolerances) -> String {
    format!(
        "tolerances: silhouette mismatches <= {:.2e}, seam mismatches <= {:.2e}, rel distance <= {:.1e}, rel depth <= {:.1e}, normal <= {} deg",
        t.max_mismatch_fraction, t.max_seam_fraction, t.rel_distance, t.rel_depth, t.normal_deg
    )
}

/// `PASS`, or `FAIL:` and one indented line per broken tolerance.
pub fn verdict_lines(failures: &[String]) -> String {
    if failures.is_empty() {
        return "PASS".into();
    }
    let mut s = String::from("FAIL:");
    for f in failures {
        s += &format!("\n  {f}");
    }
    s
}
