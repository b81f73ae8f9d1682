//! Identical and near-identical configurations among the rows of a calibration: rows whose
//! joints all lie within [`DUPLICATE_TOLERANCE_DEG`] of each other (and that aim at the same
//! target) are copies of one configuration. Copies add equations but no new information
//! about the geometry (a systematic error repeats with them), so standard deviations and the
//! residual std count distinct configurations ([`Duplicates::effective`]) and K-fold
//! cross-validation keeps every copy in one fold ([`Duplicates::group`]).

/// Joint distance (largest difference over the joints) below which two rows are the same
/// configuration, deg: an industrial arm repeats a pose to about 0.01-0.03 mm, a few
/// thousandths of a degree at its joints; 0.01 deg covers a re-taught or re-played pose and
/// stays far below the spacing of designed configurations (degrees).
pub const DUPLICATE_TOLERANCE_DEG: f64 = 0.01;

/// The joint distance below which rows are copies, as the message states it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Tolerance {
    /// Angle, deg.
    Deg(f64),
    /// Length, with its unit.
    Length(f64, &'static str),
}

impl std::fmt::Display for Tolerance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Tolerance::Deg(v) => write!(f, "{} deg", (v * 1e6).round() / 1e6),
            Tolerance::Length(v, u) => write!(f, "{} {u}", (v * 1e6).round() / 1e6),
        }
    }
}

/// How the rows of a calibration group into distinct configurations.
#[derive(Debug, Clone, PartialEq)]
pub struct Duplicates {
    /// The joint distance used.
    pub tolerance: Tolerance,
    /// Rows.
    pub rows: usize,
    /// Distinct configurations.
    pub distinct: usize,
    /// Configuration of each row (0-based, numbered in order of first appearance).
    pub group: Vec<usize>,
}

/// Residual degrees of freedom, residual std and the factor on standard deviations when
/// only distinct configurations count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Effective {
    /// Distinct equations minus identified unknowns.
    pub dof: usize,
    /// Residual std over the distinct configurations (`None` with zero dof).
    pub sigma: Option<f64>,
    /// Factor taking the standard deviations of all rows to those of the distinct ones
    /// (`None` with zero dof: undefined).
    pub std_factor: Option<f64>,
}

impl Duplicates {
    /// Rows that copy an earlier one.
    pub fn repeated(&self) -> usize {
        self.rows - self.distinct
    }

    /// The configurations with more than one row, as 1-based row numbers, largest first.
    pub fn copies(&self) -> Vec<Vec<usize>> {
        let mut g: Vec<Vec<usize>> = vec![Vec::new(); self.distinct];
        for (row, &c) in self.group.iter().enumerate() {
            g[c].push(row + 1);
        }
        g.retain(|r| r.len() > 1);
        g.sort_by(|a, b| b.len().cmp(&a.len()));
        g
    }

    /// A sentence for the verdict: how many rows copy others, and which.
    pub fn message(&self) -> String {
        let copies = self.copies();
        let shown: Vec<String> = copies
            .iter()
            .take(3)
            .map(|rows| {
                let r: Vec<String> = rows.iter().take(6).map(usize::to_string).collect();
                let more = if rows.len() > 6 { ", ..." } else { "" };
                format!("rows {}{more}", r.join(", "))
            })
            .collect();
        format!(
            "{} of {} rows repeat another configuration (joints within {}): {} distinct \
             configurations in {} groups of copies (e.g. {}); standard deviations and \
             residual_std count the {} distinct configurations only",
            self.repeated(),
            self.rows,
            self.tolerance,
            self.distinct,
            copies.len(),
            shown.join("; "),
            self.distinct
        )
    }

    /// Degrees of freedom, residual std and std factor counting distinct configurations: a
    /// fit of `equations` rows (the same number per row) with `unknowns` identified unknowns,
    /// sum of squared residuals `ssr`, residual std `sigma`. The distinct rows alone would
    /// give `equations * distinct / rows` equations, a sum of squares `ssr * distinct /
    /// rows` and a covariance `rows / distinct` times larger.
    pub fn effective(&self, equations: usize, unknowns: usize, ssr: f64, sigma: f64) -> Effective {
        let share = self.distinct as f64 / self.rows.max(1) as f64;
        let eq = (equations as f64 * share).round() as usize;
        let dof = eq.saturating_sub(unknowns);
        if dof == 0 {
            return Effective {
                dof,
                sigma: None,
                std_factor: None,
            };
        }
        let s = (ssr * share / dof as f64).sqrt();
        let factor = if sigma > 0.0 && sigma.is_finite() {
            (1.0 / share).sqrt() * s / sigma
        } else {
            (1.0 / share).sqrt()
        };
        Effective {
            dof,
            sigma: Some(s),
            std_factor: Some(factor),
        }
    }
}

/// Group `rows` (joint values, rad or model length unit, and a target key: the ball, or 0
/// when every row aims at its own point) into configurations: two rows with the same key
/// whose joints all differ by at most `tolerance_rad` are one configuration (transitively).
pub fn find_duplicates(rows: &[(&[f64], usize)], tolerance_rad: f64) -> Duplicates {
    let n = rows.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    // Sweep in order of (key, first joint): only neighbours within the tolerance on the
    // first joint are compared.
    let first = |i: usize| rows[i].0.first().copied().unwrap_or(0.0);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        rows[a]
            .1
            .cmp(&rows[b].1)
            .then(first(a).total_cmp(&first(b)))
    });
    for (pos, &i) in order.iter().enumerate() {
        for &j in &order[pos + 1..] {
            if rows[j].1 != rows[i].1 || first(j) - first(i) > tolerance_rad {
                break;
            }
            let (a, b) = (rows[i].0, rows[j].0);
            let close =
                a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tolerance_rad);
            if close {
                let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
                if ri != rj {
                    parent[ri.max(rj)] = ri.min(rj);
                }
            }
        }
    }
    let mut id = vec![usize::MAX; n];
    let mut group = Vec::with_capacity(n);
    let mut distinct = 0;
    for i in 0..n {
        let r = root(&mut parent, i);
        if id[r] == usize::MAX {
            id[r] = distinct;
            distinct += 1;
        }
        group.push(id[r]);
    }
    Duplicates {
        tolerance: Tolerance::Deg(tolerance_rad.to_degrees()),
        rows: n,
        distinct,
        group,
    }
}

/// The configurations of joint rows (no target key) within [`DUPLICATE_TOLERANCE_DEG`].
pub fn duplicate_configurations<'a>(q: impl Iterator<Item = &'a [f64]>) -> Duplicates {
    let rows: Vec<(&[f64], usize)> = q.map(|q| (q, 0)).collect();
    find_duplicates(&rows, DUPLICATE_TOLERANCE_DEG.to_radians())
}

/// The groups of `group` (as [`Duplicates::group`]) in an order shuffled by
/// [`crate::util::Rng`] with `seed`, each with its members ascending: a K-fold puts the group
/// at position `n` into fold `n % k`, so every copy of a configuration lands in one fold.
/// With every item its own group, the order is the shuffled order of the items.
pub fn shuffled_groups(group: &[usize], seed: u64) -> Vec<Vec<usize>> {
    let groups = group.iter().map(|g| g + 1).max().unwrap_or(0);
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); groups];
    for (i, &g) in group.iter().enumerate() {
        members[g].push(i);
    }
    crate::util::Rng::new(seed).shuffle(&mut members);
    members
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_and_near_identical_rows_group_and_targets_stay_apart() {
        let tol = DUPLICATE_TOLERANCE_DEG.to_radians();
        let q = [
            vec![0.1, 0.2, 0.3],
            vec![0.5, 0.2, 0.3],
            vec![0.1, 0.2, 0.3],
            vec![0.1 + 0.5 * tol, 0.2, 0.3 - 0.5 * tol],
            vec![0.1, 0.2, 0.3 + 3.0 * tol],
            vec![0.1, 0.2, 0.3],
        ];
        let keys = [0, 0, 0, 0, 0, 1];
        let rows: Vec<(&[f64], usize)> =
            q.iter().zip(keys).map(|(q, k)| (q.as_slice(), k)).collect();
        let d = find_duplicates(&rows, tol);
        assert_eq!(d.group, [0, 1, 0, 0, 2, 3]);
        assert_eq!((d.rows, d.distinct, d.repeated()), (6, 4, 2));
        assert_eq!(d.copies(), [vec![1, 3, 4]]);
        assert!(d.message().contains("rows 1, 3, 4"), "{}", d.message());
    }

    #[test]
    fn shuffled_groups_keep_copies_together_and_match_a_plain_shuffle() {
        let own: Vec<usize> = (0..17).collect();
        let mut order = own.clone();
        crate::util::Rng::new(3).shuffle(&mut order);
        let flat: Vec<usize> = shuffled_groups(&own, 3).into_iter().flatten().collect();
        assert_eq!(flat, order);
        let group: Vec<usize> = (0..30).map(|i| i % 10).collect();
        let g = shuffled_groups(&group, 3);
        assert_eq!(g.len(), 10);
        assert!(
            g.iter()
                .all(|m| m.len() == 3 && m.iter().all(|i| group[*i] == group[m[0]]))
        );
    }

    #[test]
    fn effective_counts_distinct_rows() {
        // 12 configurations x 20 copies, 3 equations each, 31 unknowns.
        let d = Duplicates {
            tolerance: Tolerance::Deg(0.01),
            rows: 240,
            distinct: 12,
            group: (0..240).map(|i| i % 12).collect(),
        };
        let ssr: f64 = 20.0 * 5.0; // the 12 rows alone: SSR 5, dof 36 - 31 = 5, sigma 1
        let sigma = (ssr / (720.0 - 31.0)).sqrt();
        let e = d.effective(720, 31, ssr, sigma);
        assert_eq!(e.dof, 5);
        assert!((e.sigma.unwrap() - 1.0).abs() < 1e-12);
        // sqrt(20) for the copies' information, times the larger sigma.
        let f = 20f64.sqrt() / sigma;
        assert!((e.std_factor.unwrap() - f).abs() < 1e-12);
        assert!(d.effective(93, 31, 1.0, 1.0).std_factor.is_none());
    }
}
