//! The friction signal: the elastic window of a curve and its torque rate, block by block.
//!
//! In the elastic clamping zone the clamp force grows linearly with angle, so the torque rate
//! dT/dtheta = k_joint (0.16 P + 0.58 d2 mu_th + Dkm/2 mu_b) is proportional to the friction
//! term at constant joint stiffness (METHODS.md section 1). Production data has torque and angle
//! only, so the torque rate is the friction signal there.
//!
//! The window is found by the phase finder ([`crate::physics::phases::find_phases`]), between two
//! fractions of the rise above the prevailing torque. The window is cut into blocks of equal angle; in each block the torque
//! rate is a least-squares slope. Disjoint blocks give independent slopes under white noise, and
//! equal angle (rather than equal sample count) keeps each slope's variance from growing when
//! the tool slows down near the target (HDT).

use crate::error::{Result, TightscanError};
use crate::sample::Sample;

/// How the elastic window is found.
#[derive(Clone, Debug, PartialEq)]
pub struct ElasticZoneConfig {
    /// Window starts where torque first exceeds this fraction of the rise (base to peak) on the
    /// way to the peak.
    pub start_fraction: f64,
    /// Window ends where torque first reaches this fraction of the rise.
    pub end_fraction: f64,
    /// Share of the window's angle span trimmed off each end. The window's ends are found on
    /// noisy torque, so the samples next to them are a selected, truncated sample of the noise;
    /// trimming by angle (which is nearly noise-free) removes them without new selection.
    pub trim_fraction: f64,
    /// Fewest samples in the window (and in the curve).
    pub min_samples: usize,
}

impl Default for ElasticZoneConfig {
    fn default() -> Self {
        // From 20 % of the rise: above the seating zone of the hardest joints (its end lies at up to
        // about 12 % of the rise), where a lower start raised the break scan's false alarms from 1.3 %
        // to 2 %. Up to the peak: a friction rise late in the curve makes the torque jump to the
        // target and the tool stop at once, so the change sits in the last samples (a 97 % end
        // with 5 % trim missed 4 % of the changes of 15 % or more); yield, when there is some,
        // cuts the window below it. Trim 1 %: enough to drop the samples selected by the level
        // crossings, with no measurable cost in false alarms (0.91 % against 0.92 %).
        Self { start_fraction: 0.2, end_fraction: 1.0, trim_fraction: 0.01, min_samples: 30 }
    }
}

/// How the window is cut into blocks and which blocks train the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockConfig {
    /// Most blocks per window.
    pub max_blocks: usize,
    /// Fewest samples per block on average (fewer samples give fewer, wider blocks).
    pub min_block_samples: usize,
    /// Share of the blocks, from the start of the window, that trains reference and scale.
    pub training_fraction: f64,
    /// Fewest training blocks.
    pub min_training_blocks: usize,
}

impl Default for BlockConfig {
    fn default() -> Self {
        Self { max_blocks: 40, min_block_samples: 5, training_fraction: 0.25, min_training_blocks: 8 }
    }
}

impl ElasticZoneConfig {
    /// Checks every field, naming the one out of range.
    pub fn validate(&self) -> Result<()> {
        let ok = |c: bool, name: &str, msg: String| if c { Ok(()) } else { Err(TightscanError::parameter(name, msg)) };
        ok(
            self.start_fraction > 0.0 && self.start_fraction < 1.0,
            "zone_start_fraction",
            format!("must be in (0, 1), got {}", self.start_fraction),
        )?;
        ok(
            self.end_fraction > self.start_fraction && self.end_fraction <= 1.0,
            "zone_end_fraction",
            format!("must be in (zone_start_fraction, 1], got {}", self.end_fraction),
        )?;
        ok(
            (0.0..0.25).contains(&self.trim_fraction),
            "zone_trim_fraction",
            format!("must be in [0, 0.25), got {}", self.trim_fraction),
        )?;
        ok(self.min_samples >= 10, "zone_min_samples", format!("must be >= 10, got {}", self.min_samples))
    }
}

impl BlockConfig {
    /// Checks every field, naming the one out of range.
    pub fn validate(&self) -> Result<()> {
        let ok = |c: bool, name: &str, msg: String| if c { Ok(()) } else { Err(TightscanError::parameter(name, msg)) };
        ok(self.max_blocks >= 4, "max_blocks", format!("must be >= 4, got {}", self.max_blocks))?;
        ok(
            self.min_block_samples >= 3,
            "min_block_samples",
            format!("must be >= 3 (a slope and a residual), got {}", self.min_block_samples),
        )?;
        ok(
            self.training_fraction > 0.0 && self.training_fraction < 1.0,
            "training_fraction",
            format!("must be in (0, 1), got {}", self.training_fraction),
        )?;
        ok(
            self.min_training_blocks >= 2 && self.min_training_blocks < self.max_blocks,
            "min_training_blocks",
            format!("must be in [2, max_blocks), got {}", self.min_training_blocks),
        )
    }
}

/// Sample range of the elastic window, `[start, end)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElasticWindow {
    /// First sample.
    pub start: usize,
    /// One past the last sample.
    pub end: usize,
    /// Highest torque of the curve [Nm].
    pub peak: f64,
}

/// Why no window could be found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WindowError {
    /// Torque never varies.
    FlatTorque,
    /// Torque varies but never rises above its prevailing (rundown) level: no elastic rise.
    NoRise,
    /// The window holds too few samples.
    TooShort(usize),
    /// Angle does not advance across the window.
    AngleStuck,
}

/// Least-squares sums of one block, x = angle relative to the block's left edge and
/// y = torque relative to the window's first sample (both small, so no cancellation).
#[derive(Clone, Copy, Debug, Default)]
pub struct BlockStats {
    /// Samples in the block.
    pub n: usize,
    /// First sample index.
    pub first: usize,
    /// Last sample index.
    pub last: usize,
    /// Left edge of the block relative to the window start [deg].
    pub offset: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    syy: f64,
}

impl BlockStats {
    /// Centred sum of squares of x.
    pub fn sxx_c(&self) -> f64 {
        self.sxx - self.sx * self.sx / self.n as f64
    }
    fn sxy_c(&self) -> f64 {
        self.sxy - self.sx * self.sy / self.n as f64
    }
    /// Least-squares torque rate [Nm/deg].
    pub fn slope(&self) -> f64 {
        self.sxy_c() / self.sxx_c()
    }
    /// Intercept at the block's left edge.
    pub fn intercept(&self) -> f64 {
        (self.sy - self.slope() * self.sx) / self.n as f64
    }
    /// Residual sum of squares of the block's own line.
    pub fn rss(&self) -> f64 {
        let syy_c = self.syy - self.sy * self.sy / self.n as f64;
        (syy_c - self.sxy_c() * self.sxy_c() / self.sxx_c()).max(0.0)
    }
}

/// Pooled least-squares sums over several blocks, in window coordinates.
#[derive(Clone, Copy, Debug, Default)]
pub struct PooledFit {
    n: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
}

impl PooledFit {
    /// Adds a block, shifting its x by its offset: sum (x + o) = sx + n o, etc.
    pub fn add(&mut self, b: &BlockStats) {
        let (n, o) = (b.n as f64, b.offset);
        self.n += n;
        self.sx += b.sx + n * o;
        self.sy += b.sy;
        self.sxx += b.sxx + 2.0 * o * b.sx + n * o * o;
        self.sxy += b.sxy + o * b.sy;
    }
    /// Least-squares slope of all samples added.
    pub fn slope(&self) -> f64 {
        let sxx_c = self.sxx - self.sx * self.sx / self.n;
        (self.sxy - self.sx * self.sy / self.n) / sxx_c
    }
}

/// Blocks of one window: stats per block (including blocks too thin to give a slope) and the
/// block width.
#[derive(Clone, Debug, Default)]
pub struct Blocks {
    /// One entry per block, in angle order.
    pub stats: Vec<BlockStats>,
    /// Width of a block [deg].
    pub width: f64,
    /// Scale of the regressor against angle: 1 for angle itself, the whitening filter's gain
    /// at low frequency for whitened samples (see [`block_stats_whitened`]).
    pub regressor_scale: f64,
}

impl Blocks {
    /// True when block `b` has a usable slope (3+ samples and angle spread).
    pub fn usable(&self, b: usize) -> bool {
        let s = &self.stats[b];
        // A block whose angles barely differ has no slope; the relative floor absorbs rounding.
        s.n >= 3 && s.sxx_c() > 1e-9 * (self.width * self.regressor_scale).powi(2)
    }
}

/// Cuts the window into `n_blocks` blocks of equal angle and accumulates each one's sums.
pub fn block_stats<A: Sample, T: Sample>(
    angle: &[A],
    torque: &[T],
    window: ElasticWindow,
    n_blocks: usize,
    out: &mut Blocks,
) {
    let a0 = angle[window.start].to_f64();
    let t0 = torque[window.start].to_f64();
    let span = angle[window.end - 1].to_f64() - a0;
    let width = span / n_blocks as f64;
    out.width = width;
    out.regressor_scale = 1.0;
    out.stats.clear();
    out.stats.extend((0..n_blocks).map(|b| BlockStats {
        first: usize::MAX,
        offset: b as f64 * width,
        ..BlockStats::default()
    }));
    let inv = 1.0 / width;
    for i in window.start..window.end {
        let x = angle[i].to_f64() - a0;
        let b = ((x * inv) as isize).clamp(0, n_blocks as isize - 1) as usize;
        let s = &mut out.stats[b];
        let xl = x - s.offset;
        let y = torque[i].to_f64() - t0;
        s.n += 1;
        s.first = s.first.min(i);
        s.last = s.last.max(i);
        s.sx += xl;
        s.sy += y;
        s.sxx += xl * xl;
        s.sxy += xl * y;
        s.syy += y * y;
    }
}

/// Blocks of equal angle over samples whose regression was whitened: `position` (the recorded
/// angle, relative to the window start, increasing) says which block a sample falls in, and each
/// block's sums are those of the whitened torque `y` on the whitened regressor `x`
/// ([`crate::detectors::noise`]). Blocks span `position[0]` to its last value; `first` and
/// `last` index these slices; offsets are 0 (the sums are of `x` itself). `gain` is the
/// whitening filter's gain at low frequency, 1 - sum phi_j.
pub fn block_stats_whitened(position: &[f64], x: &[f64], y: &[f64], n_blocks: usize, gain: f64, out: &mut Blocks) {
    let lo = position[0];
    let span = position[position.len() - 1] - lo;
    let width = span / n_blocks as f64;
    out.width = width;
    out.regressor_scale = gain.abs().max(f64::MIN_POSITIVE);
    out.stats.clear();
    out.stats.extend((0..n_blocks).map(|_| BlockStats { first: usize::MAX, ..BlockStats::default() }));
    let inv = 1.0 / width;
    for (i, ((&p, &xi), &yi)) in position.iter().zip(x).zip(y).enumerate() {
        let b = (((p - lo) * inv) as isize).clamp(0, n_blocks as isize - 1) as usize;
        let s = &mut out.stats[b];
        s.n += 1;
        s.first = s.first.min(i);
        s.last = s.last.max(i);
        s.sx += xi;
        s.sy += yi;
        s.sxx += xi * xi;
        s.sxy += xi * yi;
        s.syy += yi * yi;
    }
}

/// Encoder resolution of an angle series (relative, sorted non-decreasing within runs): the
/// grid that every step between consecutive samples is a whole multiple of, or failing one the
/// smallest step where nine in ten steps are its multiples; 0 for unquantised angles.
///
/// The smallest step need not be the grid: a tool turning 2.98 encoder steps a sample records
/// steps of 2 and 3 counts, never one. Taking the smallest step or nothing left the angle's slow
/// quantisation beat (one count every 50 samples) in the break scan's regressor and switched
/// its encoder-step check off: on the independent generator's clean CST curves (2 kHz, 0.1 deg,
/// white noise, 4,000 curves) the 194 within 0.05 steps a sample below a whole number alarmed
/// at 4.6 % (9; 2 on the same curves with a 0.001 deg encoder), the rest at 0.5 %.
pub fn encoder_resolution(x: &[f64]) -> f64 {
    encoder_resolution_at(x, 0.0)
}

/// [`encoder_resolution`] of angles `x` measured from `origin` (the recorded angles are
/// `origin` plus `x`): single precision's rounding of the recorded angle is what the steps
/// carry beside the encoder's counts, and it is set by the recorded angle's magnitude.
pub fn encoder_resolution_at(x: &[f64], origin: f64) -> f64 {
    let mut smallest = f64::INFINITY;
    for w in x.windows(2) {
        let d = w[1] - w[0];
        if d > 1e-9 && d < smallest {
            smallest = d;
        }
    }
    if !smallest.is_finite() {
        return 0.0;
    }
    let on_grid = |grid: f64| {
        let hits = x
            .windows(2)
            .filter(|w| {
                let q = (w[1] - w[0]) / grid;
                (q - q.round()).abs() < 0.05
            })
            .count();
        hits * 10 >= 9 * (x.len() - 1)
    };
    // Refined while a step lies off the grid: the common divisor of the grid and that step, by
    // Euclid's algorithm on the remainders (to the nearest multiple), stopped where a remainder
    // is within the grid test's tolerance of nothing. Nine in ten on the smallest step's grid is
    // not enough: a tool turning 3.02 steps a sample steps by 3 counts 49 times in 50 and by 4
    // once, and 0.3 deg taken for the encoder's step tripled its check. A divisor under a 64th
    // of the smallest step is no encoder's: then the coarsest grid nine in ten steps are on, or
    // none.
    let off_grid = |grid: f64| {
        x.windows(2).map(|w| w[1] - w[0]).find(|&d| {
            let q = d / grid;
            d > 1e-9 && (q - q.round()).abs() >= 0.05
        })
    };
    let fallback = || if on_grid(smallest) { smallest } else { 0.0 };
    let mut grid = smallest;
    for _ in 0..8 {
        let Some(off) = off_grid(grid) else { return finer_count(x, origin, grid) };
        let (mut a, mut b) = (off.max(grid), off.min(grid));
        loop {
            let remainder = (a - (a / b).round() * b).abs();
            if remainder < 0.05 * b {
                break;
            }
            (a, b) = (b, remainder);
            if b < smallest / 64.0 {
                return finer_count(x, origin, fallback());
            }
        }
        grid = b;
    }
    finer_count(x, origin, fallback())
}

/// The count of a fine encoder read at a low rate, under the grid `grid` that every step is a
/// multiple of to within the grid test's tolerance (a twentieth of it). A tool turning 120.4
/// counts of a 0.01 deg encoder a sample steps by 1.20 and 1.21 deg, and 1.21 is within 1 % of
/// "one step" of 1.20: the grid came out as a whole sample's advance, and the break scan's
/// encoder-step check then asked a break for a jump of 1.5 samples' worth of torque rise. No
/// break passed it: the default rule raised no false alarm and no break alarm at all on
/// CST curves at 500 Hz with a 0.01 deg encoder, on either generator (51 and 170 times the
/// count), nor on half the independent generator's CST curves at 2 kHz. What tells the count
/// is how consecutive steps differ: by whole counts (0, 1, now and then 2), where they differ
/// by more than single precision leaves of an angle (angles are often stored as float32). The
/// count is the median of the differences near the smallest of them, accepted when nine in ten
/// differences (two at least) lie within a quarter count of a whole number of it. (Euclid's
/// algorithm, as for the coarser grid, divides the float32 error of a one-count remainder into
/// a grid of a hundred counts and more, and loses it.)
fn finer_count(x: &[f64], origin: f64, grid: f64) -> f64 {
    if !(grid > 0.0) {
        return grid;
    }
    let scale = x.iter().fold(0.0_f64, |m, v| m.max((origin + v).abs()));
    let float_noise = 4.0 * f64::from(f32::EPSILON) * scale;
    let steps: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).filter(|&d| d > 1e-9).collect();
    let mut differences: Vec<f64> = steps.windows(2).map(|w| (w[1] - w[0]).abs()).filter(|&d| d > 2.0 * float_noise).collect();
    let Some(smallest) = differences.iter().copied().reduce(f64::min) else { return grid };
    if smallest >= 0.5 * grid {
        return grid;
    }
    let mut near: Vec<f64> = differences.iter().copied().filter(|&d| d < 1.5 * smallest).collect();
    if near.is_empty() {
        return grid;
    }
    let middle = near.len() / 2;
    let (_, &mut count, _) = near.select_nth_unstable_by(middle, f64::total_cmp);
    let all = differences.len();
    differences.retain(|&d| {
        let q = d / count;
        (q - q.round()).abs() < 0.25
    });
    let on_count = differences.len();
    if on_count >= 2 && on_count * 10 >= 9 * all {
        count
    } else {
        grid
    }
}

/// Where the tool resumed after the last stop that the recorder did not sample: a tool that
/// stands still while its controller waits often records nothing, so the stop shows as a gap in
/// time (more than three times the window's median sample interval) rather than as a run of
/// unchanged angle. Returns the first sample after the gap at which the torque has regained its
/// last high before the gap (it relaxes as the tool slows, then winds up again faster than
/// friction would raise it), and that high. `None` without such a gap.
pub fn resumed_after_time_gap<T: Sample, S: Sample>(
    torque: &[T],
    time: &[S],
    window: ElasticWindow,
    scratch: &mut Vec<f64>,
) -> Option<(usize, usize)> {
    let (start, end) = (window.start, window.end);
    if end < start + 3 || time.len() < end {
        return None;
    }
    scratch.clear();
    scratch.extend((start + 1..end).map(|i| time[i].to_f64() - time[i - 1].to_f64()));
    let mid = scratch.len() / 2;
    let median = *scratch.select_nth_unstable_by(mid, f64::total_cmp).1;
    if !(median > 0.0) {
        return None;
    }
    let gap = (start + 1..end).rev().find(|&g| time[g].to_f64() - time[g - 1].to_f64() > 3.0 * median)?;
    let mut high = gap - 1;
    while high > start && torque[high - 1].to_f64() >= torque[high].to_f64() {
        high -= 1;
    }
    let level = torque[high].to_f64();
    Some((high, (gap..end).find(|&k| torque[k].to_f64() >= level).unwrap_or(end)))
}

/// The part of the window free of relaxation dips that no friction change explains. A tool
/// that pauses or slows hard lets the torsion relax: the torque falls, then winds up again at
/// many times the elastic rate once the tool turns (the real Rexroth runs pause inside the final
/// step, and their recorder samples through it; between steps the torque falls to nothing and
/// is wound up again within a degree or two). A friction decrease also makes the torque fall,
/// but at once (one sample, a few through a filtered channel), and then rises at the new, lower
/// elastic rate; an intermittent change that ends jumps back at once too. So a dip counts when
/// it falls by more than six noise sd (robust, from the detrended first differences) over at
/// least three samples, and regains the elastic line over at least three samples at three times
/// the elastic torque rate `rate` or faster.
///
/// Whether the rewind is fast is judged where the torque regains its old level; the rewind has
/// ended only where the torque is back on the elastic line it left, extended over the angle the
/// rewind took (the level at the dip plus `rate` times the angle since): at the old level the
/// socket is still winding up, and the kink where the rewind meets the line was a break (the
/// Rexroth runs advance a degree or two while winding up). The search runs up to the curve's
/// peak (`peak_index`), past the window's end; where the torque never regains the extended line
/// (the controller stops at its target first), the old level serves.
///
/// The longer of the two parts is tested: a dip the curve comes back from with at least as many
/// window samples after it as before it moves the window's start to where it came back; the
/// first dip it comes back from later ends the window before the dip, and the samples from
/// there on (the tail to the peak included) are not tested. (The real Rexroth runs pause a few
/// degrees before the target: the part before the pause is then the one left.) Dips inside `stops` (recorded pauses, handled
/// by [`stop_ranges`]) are skipped, and so are intermittent friction episodes
/// (`friction_episode`). `None` when no dip counts.
pub fn without_relaxation<A: Sample, T: Sample>(
    angle: &[A],
    torque: &[T],
    window: ElasticWindow,
    rate: f64,
    peak_index: usize,
    stops: &[(f64, f64)],
    scratch: &mut Vec<f64>,
) -> Option<RelaxationFree> {
    let (start, end) = (window.start, window.end);
    if end < start + 4 || !(rate > 0.0) {
        return None;
    }
    let last = peak_index.max(end - 1).min(angle.len().min(torque.len()) - 1);
    let (a, t) = (|i: usize| angle[i].to_f64(), |i: usize| torque[i].to_f64());
    let noise_sd = difference_noise_sd(angle, torque, window, rate, scratch);
    let a0 = a(start);
    // The window's mean advance per sample: a tool that slows to let the torque relax advances
    // far less while it falls.
    let typical_step = (a(end - 1) - a0) / (end - 1 - start) as f64;
    let mut found = None;
    let mut i = start + 1;
    while i < end {
        if t(i) >= t(i - 1) {
            i += 1;
            continue;
        }
        let high = i - 1;
        let level = t(high);
        let mut low = i;
        while low < last && t(low + 1) <= t(low) {
            low += 1;
        }
        let drop = level - t(low);
        let in_stop = stops.iter().any(|&(lo, hi)| a(high) - a0 >= lo && a(high) - a0 <= hi);
        if drop > 6.0 * noise_sd && low - high >= 3 && !in_stop {
            let regained = (low..=last).find(|&k| t(k) >= level);
            if let Some(k_level) = regained {
                if k_level - low >= 3
                    && drop >= 3.0 * rate * (a(k_level) - a(low))
                    && !friction_episode(&t, &a, (high, low, k_level), drop, typical_step)
                {
                    // `level` is the sample before the fall, a noise sd or so above the line on
                    // average: the line is reached within a few noise sds of its extension.
                    let line = |k: usize| level + rate * (a(k) - a(high)).max(0.0) - BACK_ON_LINE_SDS * noise_sd;
                    let k = (k_level..=last).find(|&k| t(k) >= line(k)).unwrap_or(k_level);
                    let tested_start = match found {
                        Some(RelaxationFree::Resumed(w)) => w.start,
                        _ => start,
                    };
                    if after_is_longer(tested_start, high, k, end) {
                        found = Some(RelaxationFree::Resumed(ElasticWindow { start: k, ..window }));
                    } else {
                        return Some(RelaxationFree::EndsBeforeDip(ElasticWindow { start: tested_start, end: high + 1, ..window }));
                    }
                }
            }
        }
        i = low + 1;
    }
    found
}

/// True when a dip from sample `high` to `low`, regained at `k_level`, is an intermittent friction
/// episode rather than a relaxation: the torque fell at once (one sample carries at least
/// [`AT_ONCE`] of the `drop`) and jumped back at once, and the tool kept turning through the dip
/// (at least half the window's mean advance per sample, `typical_step`, from `high` to
/// `k_level`).
///
/// Why: a relaxation comes with the tool slowing or standing; it falls over several samples and
/// is wound up over several more. A dip's fall is `high..low`, the samples while the torque does
/// not rise, so the noise of the samples after a one-sample fall can make a friction step look
/// three samples long. On the built-in simulator's intermittent faults (15-45 %, 1,500 curves a
/// cell) the windows of 3 of the 8 missed changes on white noise and 8 of the 12 on noise growing
/// with the torque ended at such an episode's start, with every sample of the change untested.
/// The real Rexroth runs' pauses, sampled at about 830 Hz, also fall and wind up in a sample or
/// two (two thirds of the drop in one), but with the angle standing still or stepping back: the
/// advance tells them apart. It is judged over the whole dip: over the fall alone a fast
/// channel's encoder often shows no advance (at 10 kHz, 0.1 deg, half the gain was lost).
fn friction_episode(t: &impl Fn(usize) -> f64, a: &impl Fn(usize) -> f64, (high, low, k_level): (usize, usize, usize), drop: f64, typical_step: f64) -> bool {
    let largest_fall = (high + 1..=low).map(|k| t(k - 1) - t(k)).fold(0.0, f64::max);
    let largest_rise = (low + 1..=k_level).map(|k| t(k) - t(k - 1)).fold(0.0, f64::max);
    let turning = typical_step > 0.0 && a(k_level) - a(high) >= 0.5 * (k_level - high) as f64 * typical_step;
    turning && largest_fall >= AT_ONCE * drop && largest_rise >= AT_ONCE * drop
}

/// The share of a dip's drop one sample must carry, on the way down and on the way back, for
/// [`friction_episode`]: a relaxation spreads both over at least three samples (a third each at
/// most, as the Rexroth runs' wind-ups and the simulator's slowing tools make them).
const AT_ONCE: f64 = 0.6;

/// True when a controller event between samples `high` (the last before it) and `resumed` (the
/// first after it) leaves at least as many window samples after it (up to `end`) as before it
/// (from `start`): the side the detectors then test ([`without_relaxation`], and the engine for
/// unsampled pauses).
pub fn after_is_longer(start: usize, high: usize, resumed: usize, end: usize) -> bool {
    end.saturating_sub(resumed) >= (high + 1).saturating_sub(start)
}

/// How many noise sds below the extended elastic line a wound-up torque counts as back on it
/// ([`without_relaxation`]): the line is extended from one sample, the last before the fall,
/// which sits above the line by its noise.
pub const BACK_ON_LINE_SDS: f64 = 3.0;

/// Robust noise sd of the window's torque about the elastic line `rate`, from the first
/// differences (their MAD; the differences of white noise have sd sqrt(2) sigma). A fall or a
/// wind-up moves few differences, so the MAD hardly sees them.
pub fn difference_noise_sd<A: Sample, T: Sample>(
    angle: &[A],
    torque: &[T],
    window: ElasticWindow,
    rate: f64,
    scratch: &mut Vec<f64>,
) -> f64 {
    let (a, t) = (|i: usize| angle[i].to_f64(), |i: usize| torque[i].to_f64());
    scratch.clear();
    scratch.extend((window.start + 1..window.end).map(|i| (t(i) - t(i - 1)) - rate * (a(i) - a(i - 1))));
    if scratch.is_empty() {
        return 0.0;
    }
    let mid = scratch.len() / 2;
    let centre = *scratch.select_nth_unstable_by(mid, f64::total_cmp).1;
    scratch.iter_mut().for_each(|d| *d = (*d - centre).abs());
    let mad = *scratch.select_nth_unstable_by(mid, f64::total_cmp).1;
    1.4826 * mad / std::f64::consts::SQRT_2
}

/// What [`without_relaxation`] made of the window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RelaxationFree {
    /// The window starts where the torque came back from its last relaxation dip.
    Resumed(ElasticWindow),
    /// The window ends before a dip the torque did not come back from in time; nothing after
    /// it is friction.
    EndsBeforeDip(ElasticWindow),
}

/// Number of blocks for a window of `len` samples.
pub fn block_count(len: usize, cfg: &BlockConfig) -> usize {
    (len / cfg.min_block_samples).min(cfg.max_blocks)
}


/// How many times the window's mean run of unchanged angle a stop lasts at least
/// ([`stop_ranges`]). At 500 Hz with a 0.5 deg encoder a count lasts a few samples and the
/// independent generator's CSDT pause 12-80: at ten times the mean run most pauses stayed in the
/// window, whose relaxation and wind-up the break test took for a change (3.9 % false alarms of
/// 974 clean curves; 1.1 % of 891 at six times, the 83 curves more that go undecided being
/// those whose window after the pause is too short). An HDT tool slowing about fourfold through
/// the window makes runs up to about four times the mean: the HDT cells of the rates x encoders
/// grid did not move.
pub const STOP_RUN_FACTOR: usize = 6;

/// How many times its own length the wind-up's tail is left out after the torque regains its
/// level at the stop ([`stop_ranges`]), where the wind-up took at least
/// [`WINDUP_TAIL_MIN_SAMPLES`]. The torque regains that level below the elastic line extended
/// across the stop (the shaft has turned on meanwhile) and approaches the line from below: on
/// the built-in simulator's clean CSDT curves at 10 kHz (wind-up a median 6 samples) the first
/// kept samples lay 1.2 noise sds below the line, and 0.35 sd still 12 samples on; the break
/// scan and the CUSUM read that as a change (the size grid's CSDT 10 kHz 0.01 deg cells: white
/// 1.95 %, t4 1.25 % at 2,000 curves; 1.55 % and 0.95 % with the tail left out, the first kept
/// samples 0.4 sd below the line). A wind-up of a sample or two (500 Hz, or a tool that restarts
/// at once: the independent generator's) has no such tail, and its windows keep their samples.
pub const WINDUP_TAIL_FACTOR: usize = 2;

/// See [`WINDUP_TAIL_FACTOR`].
pub const WINDUP_TAIL_MIN_SAMPLES: usize = 3;

/// Angle ranges, relative to the window start, to leave out of the friction signal because the
/// tool stopped there (a CSDT pause). At standstill the torque relaxes; after the restart it is
/// wound up again, faster than friction would raise it. Neither is friction, so every block from
/// the stop until the torque regains its level at the stop is left out, and the wind-up's tail
/// after it ([`WINDUP_TAIL_FACTOR`]).
///
/// A stop is a run of unchanged angle [`STOP_RUN_FACTOR`] times longer than the window's mean
/// run (and at least ten samples): quantised angle at low speed repeats too, but not for that
/// long.
pub fn stop_ranges<A: Sample, T: Sample>(angle: &[A], torque: &[T], window: ElasticWindow, out: &mut Vec<(f64, f64)>) {
    out.clear();
    let (start, end) = (window.start, window.end);
    let run_end = |i: usize| {
        let a = angle[i].to_f64();
        let mut j = i + 1;
        while j < end && angle[j].to_f64() == a {
            j += 1;
        }
        j
    };
    let mut runs = 0usize;
    let mut i = start;
    while i < end {
        i = run_end(i);
        runs += 1;
    }
    let stop_len = ((STOP_RUN_FACTOR * (end - start)) / runs.max(1)).max(10);
    let a0 = angle[start].to_f64();
    let mut i = start;
    while i < end {
        let j = run_end(i);
        if j - i >= stop_len {
            let level = torque[i].to_f64();
            let mut k = j;
            while k < end && torque[k].to_f64() < level {
                k += 1;
            }
            let wind_up = k - j;
            if wind_up >= WINDUP_TAIL_MIN_SAMPLES {
                k += WINDUP_TAIL_FACTOR * wind_up;
            }
            out.push((angle[i].to_f64() - a0, angle[k.min(end - 1)].to_f64() - a0));
        }
        i = j;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::phases::{find_phases, PhaseScratch, YieldConfig};

    /// The floor-quantised angle of a tool turning `steps` encoder steps of 0.1 deg a sample.
    fn quantised(steps: f64, n: usize) -> Vec<f64> {
        (0..n).map(|i| (1234.567 + 0.1 * steps * i as f64).div_euclid(0.1) * 0.1).collect()
    }

    #[test]
    fn encoder_resolution_is_the_steps_common_divisor() {
        // Steps of one count and two: the smallest step is the grid.
        assert!((encoder_resolution(&quantised(1.3, 200)) - 0.1).abs() < 1e-9);
        // 2.98 and 4.02 counts a sample step by 2 and 3, and by 4 and 5 counts: no step is one
        // count, and the old rule (the smallest step, or nothing) found no grid.
        for steps in [2.98, 3.02, 4.02, 5.97] {
            let r = encoder_resolution(&quantised(steps, 300));
            assert!((r - 0.1).abs() < 1e-9, "{steps} steps a sample: resolution {r}");
        }
        // A fine encoder at a low rate: 120.4 and 339.6 counts of 0.01 deg a sample step by
        // 1.20 / 1.21 and 3.39 / 3.40 deg, each within 5 % of the smaller. The grid is the count.
        for steps in [120.4, 339.6, 85.3] {
            let fine: Vec<f64> = (0..300).map(|i| ((1234.567 + 0.01 * steps * i as f64).div_euclid(0.01) * 0.01) as f32 as f64).collect();
            let r = encoder_resolution(&fine);
            assert!((r - 0.01).abs() < 1e-4, "{steps} counts of 0.01 deg a sample: resolution {r}");
        }
        // A window of a float32 recording near 1,900 deg, measured from its start: its steps of
        // 34 counts differ by whole float32 units (1.2e-4 deg there), which are no encoder's
        // count and which the window's own small angles do not show.
        let origin = 1900.0_f64;
        let recorded: Vec<f64> = (0..60).map(|i| ((origin + 0.1 * 34.02 * i as f64).div_euclid(0.1) * 0.1) as f32 as f64 - origin).collect();
        let r = encoder_resolution_at(&recorded, origin);
        assert!(r > 0.099, "34.02 counts of 0.1 deg a sample: resolution {r}");
        // A constant whole number of counts a sample: the step itself is a grid.
        let r = encoder_resolution(&quantised(3.0, 100));
        assert!(r > 0.0 && ((r / 0.1) - (r / 0.1).round()).abs() < 1e-6, "{r}");
        // An unquantised angle with uneven steps has none.
        let mut state = 7u64;
        let mut angle = 0.0;
        let free: Vec<f64> = (0..300)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                angle += 0.3 + 0.2 * (state >> 11) as f64 / (1u64 << 53) as f64;
                angle
            })
            .collect();
        assert_eq!(encoder_resolution(&free), 0.0);
    }

    #[test]
    fn window_of_a_clean_ramp() {
        // Rundown at 0.1 Nm for 100 samples, then a ramp 0.1 + 0.2 (theta - 100) up to 20 Nm.
        let angle: Vec<f64> = (0..300).map(|i| i as f64).collect();
        let torque: Vec<f64> =
            angle.iter().map(|&a| if a < 100.0 { 0.1 } else { (0.1 + 0.2 * (a - 100.0)).min(40.0) }).collect();
        let zone = ElasticZoneConfig { start_fraction: 0.3, end_fraction: 0.9, trim_fraction: 0.05, ..ElasticZoneConfig::default() };
        let w = find_phases(&angle, &torque, &zone, &YieldConfig::default(), &mut PhaseScratch::default()).map(|p| p.window);
        let w = w.unwrap_or(ElasticWindow { start: 0, end: 0, peak: 0.0 });
        // peak 39.9 at 299; base 0.1; 30 % level = 12.04 -> first sample >= it is 160; 90 %
        // level first reached at 280, so the window is 160..=279, trimmed by 5 % of 119 deg
        // (166..274) and then given back the two samples before its start (164).
        assert_eq!(w.start, 164);
        assert_eq!(w.end, 274);
        let mut blocks = Blocks::default();
        block_stats(&angle, &torque, w, 10, &mut blocks);
        for b in 0..10 {
            assert!(blocks.usable(b));
            assert!((blocks.stats[b].slope() - 0.2).abs() < 1e-12);
            assert!(blocks.stats[b].rss() < 1e-9);
        }
        let mut pooled = PooledFit::default();
        blocks.stats.iter().for_each(|b| pooled.add(b));
        assert!((pooled.slope() - 0.2).abs() < 1e-12);
        assert_eq!(blocks.stats.iter().map(|b| b.n).sum::<usize>(), 110);
    }

    #[test]
    fn flat_and_short_curves() {
        let angle: Vec<f32> = (0..50).map(|i| i as f32).collect();
        let flat = vec![1.0f32; 50];
        let phases = |t: &[f32]| find_phases(&angle, t, &ElasticZoneConfig::default(), &YieldConfig::default(), &mut PhaseScratch::default()).map(|p| p.window);
        assert_eq!(phases(&flat), Err(WindowError::FlatTorque));
        let step: Vec<f32> = (0..50).map(|i| if i < 45 { 0.0 } else { 1.0 }).collect();
        assert!(matches!(phases(&step), Err(WindowError::TooShort(_))));
    }

    /// A straight elastic line, 0.25 deg per sample at rate 0.1 Nm/deg, with a small
    /// deterministic ripple for noise, and `edit` applied to it.
    fn line_with(edit: impl Fn(usize, &mut f64)) -> (Vec<f64>, Vec<f64>) {
        let angle: Vec<f64> = (0..400).map(|i| i as f64 * 0.25).collect();
        let torque = (0..400)
            .map(|i| {
                let mut t = 1.0 + 0.1 * angle[i] + 0.002 * ((i * 7919 % 13) as f64 - 6.0) / 6.0;
                edit(i, &mut t);
                t
            })
            .collect();
        (angle, torque)
    }

    #[test]
    fn a_stop_leaves_out_its_wind_up_and_the_wind_up_s_tail() {
        // 0.01 deg a sample at 1 Nm/deg; the tool stands at sample 199's angle up to sample 239
        // (the torque relaxes by 0.2 Nm), then winds the torque up to the stop's level over 6
        // samples, and a tail approaches the line from below.
        let mut angle = Vec::new();
        let mut torque = Vec::new();
        for i in 0..600_usize {
            let moving = if i < 200 { i } else if i < 240 { 199 } else { i - 40 };
            let a = 0.01 * moving as f64;
            let t = match i {
                200..=239 => a - 0.2 * (i - 199) as f64 / 40.0,
                240..=245 => a - 0.2 + 0.2 * (i - 239) as f64 / 6.5 - 0.01 * (i - 239) as f64,
                _ if i > 245 => a - 0.06 * (-((i - 246) as f64) / 6.0).exp(),
                _ => a,
            };
            angle.push(a);
            torque.push(t);
        }
        let mut stops = Vec::new();
        stop_ranges(&angle, &torque, ElasticWindow { start: 0, end: 600, peak: 6.0 }, &mut stops);
        assert_eq!(stops.len(), 1, "{stops:?}");
        let (from, to) = stops[0];
        assert!((from - 1.99).abs() < 1e-9, "{stops:?}");
        // Back at its level after the 6-sample wind-up (sample 246, 2.06 deg), plus twice that.
        let back_at_level = torque.iter().enumerate().skip(240).find(|(_, t)| **t >= torque[199]).map_or(0, |(i, _)| i);
        assert_eq!(back_at_level, 246);
        let expected = angle[back_at_level + WINDUP_TAIL_FACTOR * (back_at_level - 240)];
        assert!((to - expected).abs() < 1e-9 && to > angle[back_at_level], "{to} vs {expected}");
        // A tool that restarts at once (back at the level in the first sample): no tail.
        let mut at_once = torque.clone();
        at_once.iter_mut().enumerate().skip(240).for_each(|(i, t)| *t = angle[i]);
        stop_ranges(&angle, &at_once, ElasticWindow { start: 0, end: 600, peak: 6.0 }, &mut stops);
        assert!((stops[0].1 - angle[240]).abs() < 1e-9, "{stops:?}");
    }

    #[test]
    fn relaxation_dips_move_or_end_the_tested_part() {
        let window = ElasticWindow { start: 0, end: 380, peak: 11.0 };
        let run = |torque: &[f64]| {
            let angle: Vec<f64> = (0..400).map(|i| i as f64 * 0.25).collect();
            without_relaxation(&angle, torque, window, 0.1, 399, &[], &mut Vec::new())
        };
        // A dip of 1 Nm over 5 samples, wound up again over 6 (at ~7 times the elastic rate).
        let dip = |at: usize| {
            move |i: usize, t: &mut f64| {
                if (at..at + 5).contains(&i) {
                    *t -= 0.2 * (i - at + 1) as f64;
                } else if (at + 5..at + 11).contains(&i) {
                    *t -= 1.0 - 0.16 * (i - at - 4) as f64;
                }
            }
        };
        // Early: tested from where the torque is back on the line, past the wind-up.
        let (_, early) = line_with(dip(100));
        match run(&early) {
            Some(RelaxationFree::Resumed(w)) => assert!((110..=113).contains(&w.start), "{w:?}"),
            other => panic!("{other:?}"),
        }
        // Late (fewer samples after it than before): the part before it.
        let (_, late) = line_with(dip(330));
        match run(&late) {
            Some(RelaxationFree::EndsBeforeDip(w)) => assert_eq!((w.start, w.end), (0, 330)),
            other => panic!("{other:?}"),
        }
        // A friction decrease: the torque falls at once and goes on at a lower rate.
        let (_, drop) = line_with(|i, t| {
            if i >= 200 {
                *t -= 0.3 * (*t - 1.0);
            }
        });
        assert_eq!(run(&drop), None);
        // An intermittent episode late in the window: the torque falls by 1 Nm at once, the two
        // samples after the fall lie lower still (as noise can put them, so the fall spans three
        // samples), and 10 samples (2.5 deg) later it jumps back at once: fast enough on average
        // to pass for a wind-up, but not a relaxation; the window is left whole.
        let (_, episode) = line_with(|i, t| match i {
            330 => *t -= 1.0,
            331 => *t -= 1.05,
            332..=341 => *t -= 1.1,
            _ => {}
        });
        assert_eq!(run(&episode), None);
        // The late relaxation dip above still ends the window.
        assert!(matches!(run(&late), Some(RelaxationFree::EndsBeforeDip(_))));
        // The same fall and return at once, but with the tool creeping at a tenth of its speed
        // through the dip (as the real Rexroth runs' pauses look at their sampling rate): a
        // relaxation.
        let standing: Vec<f64> = (0..400_usize)
            .map(|i| {
                let i = i as f64;
                0.25 * if i < 330.0 { i } else if i <= 341.0 { 329.0 + 0.1 * (i - 329.0) } else { 330.2 + (i - 341.0) }
            })
            .collect();
        assert!(matches!(
            without_relaxation(&standing, &episode, window, 0.1, 399, &[], &mut Vec::new()),
            Some(RelaxationFree::EndsBeforeDip(_))
        ));
    }
}
