//! The Jacobian of a [`PointProblem`] in row blocks ([`Problem::jacobian_blocks`]): each
//! measurement writes its rows of each column straight into the column-major block, a
//! contiguous run of three (no row-major staging copy to transpose afterwards).

use nalgebra::{DMatrix, Vector3};

use super::{PointProblem, memo_parts};
use crate::identify::Problem;
use crate::model::chain::JacobianScratch;
use crate::model::trig::TrigMemo;

impl PointProblem {
    /// [`Problem::jacobian_blocks`]: the rows split into one contiguous part per visitor
    /// (each on its own thread, with the trig memos of the measurements whose first row it
    /// holds; a measurement split between two parts is evaluated by both), each part in
    /// blocks of about `block_rows / 3` measurements, the distance rows last.
    pub(super) fn visit_jacobian_blocks(
        &self,
        x: &[f64],
        cols: Option<&[usize]>,
        block_rows: usize,
        visitors: &mut [&mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)],
    ) {
        let (at, wanted) = self.column_map(cols);
        let width = cols.map_or(self.unknown_count(), <[usize]>::len);
        let parts = visitors.len();
        if parts == 0 {
            return;
        }
        let count = self.meas.len();
        let base = 3 * count;
        let n = self.residual_count();
        let chunk = n.div_ceil(parts).max(1);
        let rows: Vec<std::ops::Range<usize>> = (0..parts)
            .map(|k| (k * chunk).min(n)..((k + 1) * chunk).min(n))
            .collect();
        // The measurements whose first row each part holds (their memos go with it).
        let owned: Vec<std::ops::Range<usize>> = rows
            .iter()
            .map(|r| r.start.min(base).div_ceil(3)..r.end.min(base).div_ceil(3))
            .collect();
        let per_block = (block_rows / 3).max(1);
        // (entry of the chain's point Jacobian, output column) of every chain unknown wanted.
        let params = self.chain.param_ids().len();
        let pairs: Vec<(usize, usize)> = self
            .cols
            .iter()
            .zip(&at)
            .filter_map(|(&col, &oc)| oc.filter(|_| col < params).map(|oc| (col, oc)))
            .collect();
        // Output columns written for every measured row (the rest are zeroed per block).
        let mut full = vec![false; width];
        for &(_, oc) in &pairs {
            full[oc] = true;
        }
        self.with_chain(x, |chain| {
            let centres = self.centres(x);
            let nj = chain.joints.len();
            let mut memos = self.trig.try_take();
            let memos = memos.as_deref_mut().filter(|v| v.len() == nj * count);
            let memos = memo_parts(memos.map(|v| &mut v[..]), &owned, nj);
            let work = |part: std::ops::Range<usize>,
                        own: std::ops::Range<usize>,
                        mut memo: Option<&mut [TrigMemo]>,
                        visit: &mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)| {
                let mut block = DMatrix::<f64>::zeros(0, width);
                let mut buf = vec![Vector3::zeros(); chain.param_ids().len()];
                let mut scratch = JacobianScratch::default();
                scratch.set_wanted(wanted.clone());
                let measured = part.start.min(base)..part.end.min(base);
                let mut first = measured.start / 3;
                while 3 * first < measured.end {
                    let last = (first + per_block).min(measured.end.div_ceil(3));
                    let lo = (3 * first).max(measured.start);
                    let hi = (3 * last).min(measured.end);
                    let len = hi - lo;
                    if block.nrows() != len {
                        block = DMatrix::zeros(len, width);
                    }
                    // Columns not written for every row (an unknown ball's, one not asked
                    // for) start at zero; each measurement then writes its rows of every
                    // other column as one short contiguous run.
                    let data = block.as_mut_slice();
                    for (oc, column) in data.chunks_exact_mut(len).enumerate() {
                        if !full[oc] {
                            column.fill(0.0);
                        }
                    }
                    for i in first..last {
                        let m = &self.meas[i];
                        let memo_i = match memo.as_deref_mut() {
                            Some(mm) if own.contains(&i) => {
                                let o = i - own.start;
                                Some(&mut mm[nj * o..nj * (o + 1)])
                            }
                            _ => None,
                        };
                        self.chain_rows(chain, i, &mut buf, &mut scratch, memo_i);
                        let ball = self.ball_slot(m);
                        // The rows a0..a1 of this measurement's three within lo..hi.
                        let (a0, a1) = (lo.max(3 * i) - 3 * i, hi.min(3 * i + 3) - 3 * i);
                        let at_row = 3 * i + a0 - lo;
                        if a1 - a0 == 3 {
                            // A fixed-size copy (a slice copy of unknown length calls memmove).
                            for &(col, oc) in &pairs {
                                let (start, v) = (oc * len + at_row, &buf[col]);
                                data[start] = v[0];
                                data[start + 1] = v[1];
                                data[start + 2] = v[2];
                            }
                        } else {
                            for &(col, oc) in &pairs {
                                for a in a0..a1 {
                                    data[oc * len + at_row + a - a0] = buf[col][a];
                                }
                            }
                        }
                        if let Some(o) = ball {
                            for a in a0..a1 {
                                if let Some(oc) = at[o + a] {
                                    data[oc * len + at_row + a - a0] = -1.0;
                                }
                            }
                        }
                    }
                    visit(lo..hi, &block);
                    first = last;
                }
                let distances = part.start.max(base)..part.end.max(base);
                if !distances.is_empty() {
                    let mut block = DMatrix::<f64>::zeros(distances.len(), width);
                    for row in distances.clone() {
                        self.distance_row(&centres, row - base, |u, v| {
                            if let Some(oc) = at[u] {
                                block[(row - distances.start, oc)] = v;
                            }
                        });
                    }
                    visit(distances, &block);
                }
            };
            let jobs: Vec<_> = rows
                .into_iter()
                .zip(owned)
                .zip(memos)
                .zip(visitors.iter_mut())
                .collect();
            crate::util::parts::for_each(jobs, &|(((part, own), memo), visit)| {
                work(part, own, memo, &mut **visit)
            });
        })
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::DMatrix;

    use crate::identify::Problem;
    use crate::measure::PointProblem;
    use crate::twin::SerialTwin;

    /// The blocks handed to the visitors are the rows of the whole Jacobian bit for bit:
    /// every column or some picked ones, one part or three (a measurement's rows split
    /// between parts), blocks of 7 rows (not a multiple of three) and of 384.
    #[test]
    fn blocks_are_the_rows_of_the_whole_jacobian() {
        let twin = SerialTwin::irb120(1);
        let p = PointProblem::new(
            twin.nominal.clone(),
            twin.nominal.param_ids(),
            twin.plate.clone(),
            twin.centring(40, 2),
        )
        .expect("twin data are consistent");
        let x = p.initial();
        let (n, m) = (p.residual_count(), p.unknown_count());
        let mut whole = DMatrix::zeros(n, m);
        p.jacobian(&x, &mut whole).unwrap();
        let picked = [m - 1, 0, 5, 17, m - 3];
        for cols in [None, Some(&picked[..])] {
            let width = cols.map_or(m, <[usize]>::len);
            for parts in [1, 3] {
                for block_rows in [7, 384] {
                    let mut got: Vec<DMatrix<f64>> =
                        vec![DMatrix::from_element(n, width, f64::NAN); parts];
                    let mut seen = vec![0usize; parts];
                    {
                        let mut visits: Vec<_> = got
                            .iter_mut()
                            .zip(seen.iter_mut())
                            .map(|(g, s)| {
                                move |rows: std::ops::Range<usize>, j: &DMatrix<f64>| {
                                    *s += rows.len();
                                    g.rows_mut(rows.start, rows.len()).copy_from(j);
                                }
                            })
                            .collect();
                        let mut visitors: Vec<
                            &mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send),
                        > = visits
                            .iter_mut()
                            .map(|v| {
                                v as &mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)
                            })
                            .collect();
                        assert!(
                            p.jacobian_blocks(&x, cols, block_rows, &mut visitors)
                                .unwrap()
                        );
                    }
                    assert_eq!(seen.iter().sum::<usize>(), n, "every row once");
                    let chunk = n.div_ceil(parts);
                    for i in 0..n {
                        let g = &got[i / chunk];
                        for c in 0..width {
                            let k = cols.map_or(c, |cs| cs[c]);
                            assert_eq!(
                                g[(i, c)].to_bits(),
                                whole[(i, k)].to_bits(),
                                "row {i} unknown {k} ({parts} parts, blocks of {block_rows})"
                            );
                        }
                    }
                }
            }
        }
    }
}
