//! ISO metric thread geometry: the one source of truth for pitch, pitch diameter, bearing
//! diameter and stress area of the bolts tightscan knows.
//!
//! Sources of the tabulated values:
//! - pitches: ISO 261 (coarse series and the common fine pitches of M8..M24);
//! - pitch diameter d2 and minor diameter d3: ISO 724 basic profile, H = (sqrt 3 / 2) P,
//!   d2 = d - 2 (3/8) H = d - 0.649519 P, d3 = d1 - H/6 = d - 1.226869 P;
//! - stress area As = pi/4 ((d2 + d3)/2)^2: ISO 898-1 (gives 36.6 mm^2 for M8, 84.3 for M12);
//! - effective bearing diameter Dkm = (dw + dh)/2 (VDI 2230 Part 1), with dw the minimum
//!   bearing-face diameter of hexagon head screws ISO 4017 (= bolts ISO 4014), product grade A,
//!   and dh the medium-series clearance hole of ISO 273. Fine-pitch screws (ISO 8676) share the
//!   head and the hole of their coarse counterpart, so they share Dkm.
//!
//! Where published tables disagree (M14 dw: 19.64 in the ISO 4014/4017 table reproduced by EN
//! ISO distributors, 19.37 in some catalogues), the value of the ISO table is used.

use std::f64::consts::PI;

/// Coefficient of the pitch diameter, ISO 724: d2 = d - `D2_PITCH_FACTOR` P (= 3 sqrt(3) / 8).
pub const D2_PITCH_FACTOR: f64 = 0.649_519;
/// Coefficient of the minor diameter used for the stress area, ISO 898-1 / ISO 724:
/// d3 = d - `D3_PITCH_FACTOR` P (= 17 sqrt(3) / 24).
pub const D3_PITCH_FACTOR: f64 = 1.226_869;
/// Lead term of the tightening equation (VDI 2230 R13/1): P / (2 pi) = 0.159 P, rounded as in
/// VDI 2230.
pub const LEAD_FACTOR: f64 = 0.16;
/// Flank term of the tightening equation (VDI 2230 R13/1): d2 / (2 cos 30 deg) = 0.577 d2,
/// rounded as in VDI 2230 (ISO 16047 evaluations use 0.578).
pub const FLANK_FACTOR: f64 = 0.58;

/// Flank term of the ISO 16047 friction evaluation: d2 / (2 cos 30 deg) = 0.5774 d2, written
/// 0.578 in ISO 16047. The evaluation constants are kept apart from the VDI 2230 model ones above
/// on purpose: each formula uses the constants of its own standard.
pub const ISO16047_FLANK_FACTOR: f64 = 0.578;
/// Lead term of the ISO 16047 evaluation: P / (2 pi).
pub const ISO16047_LEAD_FACTOR: f64 = 1.0 / (2.0 * PI);

/// The three lengths the torque model needs, from the thread table or from per-row overrides
/// (`pitch_mm`, `d2_mm`, `dkm_mm` columns or config values).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointGeometry {
    /// Pitch P \[mm\].
    pub pitch_mm: f64,
    /// Pitch diameter d2 \[mm\].
    pub d2_mm: f64,
    /// Effective bearing diameter Dkm \[mm\].
    pub dkm_mm: f64,
    /// Nominal diameter d \[mm\] (for the nut factor K = T / (F d)).
    pub nominal_diameter_mm: f64,
}

impl JointGeometry {
    /// Total friction coefficient from the torque per clamp force T/F \[Nm/kN\] (ISO 16047,
    /// assuming mu_th = mu_b): `mu_tot = (T/F - P/(2 pi)) / (0.578 d2 + Dkm/2)`.
    pub fn mu_tot(&self, torque_per_force: f64) -> f64 {
        (torque_per_force - ISO16047_LEAD_FACTOR * self.pitch_mm)
            / (ISO16047_FLANK_FACTOR * self.d2_mm + 0.5 * self.dkm_mm)
    }

    /// Nut factor K = T / (F d), dimensionless; `torque_per_force` in Nm/kN, d in mm.
    pub fn nut_factor(&self, torque_per_force: f64) -> f64 {
        torque_per_force / self.nominal_diameter_mm
    }

    /// Torque per clamp force \[Nm/kN\] that the VDI 2230 model (R13/1) gives for these
    /// friction coefficients; the inverse of [`JointGeometry::mu_tot`] up to the constants.
    pub fn torque_per_force(&self, mu_th: f64, mu_b: f64) -> f64 {
        LEAD_FACTOR * self.pitch_mm + FLANK_FACTOR * self.d2_mm * mu_th + 0.5 * self.dkm_mm * mu_b
    }
}

impl From<&ThreadGeometry> for JointGeometry {
    fn from(t: &ThreadGeometry) -> Self {
        Self {
            pitch_mm: t.pitch_mm,
            d2_mm: t.d2_mm,
            dkm_mm: t.dkm_mm,
            nominal_diameter_mm: t.nominal_diameter_mm,
        }
    }
}

/// Geometry of one ISO metric thread with a hexagon head screw in a medium clearance hole.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThreadGeometry {
    /// ISO designation: "M8" for coarse pitch, "M8x1" for a fine pitch.
    pub designation: &'static str,
    /// Nominal (major) diameter d \[mm\].
    pub nominal_diameter_mm: f64,
    /// Pitch P \[mm\].
    pub pitch_mm: f64,
    /// Pitch diameter d2 \[mm\].
    pub d2_mm: f64,
    /// Effective diameter of the head bearing friction Dkm \[mm\].
    pub dkm_mm: f64,
    /// Whether the pitch is the coarse (standard) pitch of this diameter.
    pub coarse: bool,
    /// Tensile stress area As \[mm^2\].
    pub stress_area_mm2: f64,
}

impl ThreadGeometry {
    /// Torque per unit clamp force \[Nm/kN\] for given thread and head friction coefficients:
    /// `0.16 P + 0.58 d2 mu_th + (Dkm/2) mu_b` (VDI 2230 Part 1, R13/1), so that
    /// `T = F * torque_per_force(...)` with F in kN and T in Nm, prevailing torque excluded.
    pub fn torque_per_force(&self, mu_th: f64, mu_b: f64) -> f64 {
        JointGeometry::from(self).torque_per_force(mu_th, mu_b)
    }
}

/// Builds one row from the primary data, so that every derived quantity comes from one formula.
/// `dw` = min. bearing-face diameter (ISO 4017 grade A), `dh` = medium clearance hole (ISO 273).
const fn row(
    designation: &'static str,
    d: f64,
    pitch: f64,
    coarse: bool,
    dw: f64,
    dh: f64,
) -> ThreadGeometry {
    let d2 = d - D2_PITCH_FACTOR * pitch;
    let d3 = d - D3_PITCH_FACTOR * pitch;
    let ds = 0.5 * (d2 + d3);
    ThreadGeometry {
        designation,
        nominal_diameter_mm: d,
        pitch_mm: pitch,
        d2_mm: d2,
        dkm_mm: 0.5 * (dw + dh),
        coarse,
        stress_area_mm2: 0.25 * PI * ds * ds,
    }
}

/// ISO metric threads M3..M24: every coarse pitch and the common fine pitches, sorted by nominal
/// diameter, then by decreasing pitch (so each diameter starts with its coarse pitch).
pub static ISO_METRIC_THREADS: &[ThreadGeometry] = &[
    //   designation  d     P     coarse dw     dh
    row("M3", 3.0, 0.5, true, 4.57, 3.4),
    row("M4", 4.0, 0.7, true, 5.88, 4.5),
    row("M5", 5.0, 0.8, true, 6.88, 5.5),
    row("M6", 6.0, 1.0, true, 8.88, 6.6),
    row("M8", 8.0, 1.25, true, 11.63, 9.0),
    row("M8x1", 8.0, 1.0, false, 11.63, 9.0),
    row("M10", 10.0, 1.5, true, 14.63, 11.0),
    row("M10x1.25", 10.0, 1.25, false, 14.63, 11.0),
    row("M10x1", 10.0, 1.0, false, 14.63, 11.0),
    row("M12", 12.0, 1.75, true, 16.63, 13.5),
    row("M12x1.5", 12.0, 1.5, false, 16.63, 13.5),
    row("M12x1.25", 12.0, 1.25, false, 16.63, 13.5),
    row("M14", 14.0, 2.0, true, 19.64, 15.5),
    row("M14x1.5", 14.0, 1.5, false, 19.64, 15.5),
    row("M16", 16.0, 2.0, true, 22.49, 17.5),
    row("M16x1.5", 16.0, 1.5, false, 22.49, 17.5),
    row("M18", 18.0, 2.5, true, 25.34, 20.0),
    row("M18x1.5", 18.0, 1.5, false, 25.34, 20.0),
    row("M20", 20.0, 2.5, true, 28.19, 22.0),
    row("M20x1.5", 20.0, 1.5, false, 28.19, 22.0),
    row("M22", 22.0, 2.5, true, 31.71, 24.0),
    row("M22x1.5", 22.0, 1.5, false, 31.71, 24.0),
    row("M24", 24.0, 3.0, true, 33.61, 26.0),
    row("M24x2", 24.0, 2.0, false, 33.61, 26.0),
];

/// Looks up an ISO metric thread by designation.
///
/// "M8" is the coarse pitch; "M8x1.25" (pitch equal to the coarse one) is the same entry;
/// "M10x1.25" is a fine pitch. Case, spaces, `x`/`X`/`×` and a decimal comma are tolerated
/// ("m8 x 1,25"). Returns `None` for a diameter or pitch the table does not hold.
pub fn parse_thread(designation: &str) -> Option<&'static ThreadGeometry> {
    let normalised: String = designation
        .chars()
        .filter(|c| !c.is_whitespace())
        .map(|c| match c {
            '×' | 'x' => 'X',
            'm' => 'M',
            ',' => '.',
            other => other,
        })
        .collect();
    let rest = normalised.strip_prefix('M')?;
    let (diameter, pitch) = match rest.split_once('X') {
        Some((d, p)) => (d, Some(p)),
        None => (rest, None),
    };
    let d: f64 = parse_positive(diameter)?;
    let p: Option<f64> = match pitch {
        Some(p) => Some(parse_positive(p)?),
        None => None,
    };
    // Table values are exact decimal literals, so a tolerance far below any pitch step suffices.
    let same = |a: f64, b: f64| (a - b).abs() < 1e-9;
    ISO_METRIC_THREADS.iter().find(|t| {
        same(t.nominal_diameter_mm, d)
            && match p {
                Some(p) => same(t.pitch_mm, p),
                None => t.coarse,
            }
    })
}

fn parse_positive(text: &str) -> Option<f64> {
    // Only digits and one decimal point: rejects "inf", "1e1", signs and similar surprises.
    if text.is_empty() || !text.chars().all(|c| c.is_ascii_digit() || c == '.') {
        return None;
    }
    text.parse::<f64>().ok().filter(|v| v.is_finite() && *v > 0.0)
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)] // a failed unwrap is a failed test
mod tests {
    use super::*;

    #[test]
    fn d2_formula_holds_for_every_row() {
        for t in ISO_METRIC_THREADS {
            let d2 = t.nominal_diameter_mm - 0.6495 * t.pitch_mm;
            assert!((t.d2_mm - d2).abs() < 1e-4, "{}: d2 {} vs {}", t.designation, t.d2_mm, d2);
            let d3 = t.nominal_diameter_mm - 1.2269 * t.pitch_mm;
            let as_ = PI / 4.0 * ((d2 + d3) / 2.0).powi(2);
            assert!((t.stress_area_mm2 - as_).abs() / as_ < 1e-4, "{}", t.designation);
            assert!(t.dkm_mm > t.nominal_diameter_mm, "{}", t.designation);
        }
    }

    #[test]
    fn matches_published_values() {
        // ISO 724 d2 and ISO 898-1 As as tabulated (3 significant decimals / 3 digits).
        let cases = [
            ("M6", 5.350, 20.1),
            ("M8", 7.188, 36.6),
            ("M10", 9.026, 58.0),
            ("M12", 10.863, 84.3),
            ("M16", 14.701, 157.0),
            ("M20", 18.376, 245.0),
            ("M24", 22.051, 353.0),
            ("M10x1.25", 9.188, 61.2),
            ("M12x1.5", 11.026, 88.1),
        ];
        for (name, d2, as_) in cases {
            let t = parse_thread(name).unwrap();
            assert!((t.d2_mm - d2).abs() < 6e-4, "{name} d2 {}", t.d2_mm);
            assert!(
                (t.stress_area_mm2 - as_).abs() / as_ < 3e-3,
                "{name} As {}",
                t.stress_area_mm2
            );
        }
        let m8 = parse_thread("M8").unwrap();
        assert!((m8.dkm_mm - 10.315).abs() < 1e-12);
    }

    #[test]
    fn parses_designations() {
        assert_eq!(parse_thread("M8").unwrap().designation, "M8");
        assert_eq!(parse_thread("M8x1.25").unwrap().designation, "M8");
        assert!(parse_thread("M8x1.25").unwrap().coarse);
        assert_eq!(parse_thread("m8 x 1.25").unwrap().designation, "M8");
        assert_eq!(parse_thread(" M 8 ").unwrap().designation, "M8");
        assert_eq!(parse_thread("M8X1").unwrap().designation, "M8x1");
        assert_eq!(parse_thread("M8×1").unwrap().designation, "M8x1");
        assert_eq!(parse_thread("M10x1.25").unwrap().designation, "M10x1.25");
        assert!(!parse_thread("M10x1.25").unwrap().coarse);
        assert_eq!(parse_thread("M10x1,25").unwrap().designation, "M10x1.25");
        assert_eq!(parse_thread("M10x1.0").unwrap().designation, "M10x1");
        assert_eq!(parse_thread("M24x2").unwrap().pitch_mm, 2.0);
        assert_eq!(parse_thread("M12x1.75").unwrap().designation, "M12");
    }

    #[test]
    fn unknown_is_none() {
        for bad in [
            "", "M", "M7", "M8x", "M8x1.5", "M10x0.75", "8", "M-8", "M8x-1", "Minf", "M8x1x1",
            "M30", "UNC 1/4", "M1e1",
        ] {
            assert!(parse_thread(bad).is_none(), "{bad:?} parsed");
        }
    }

    #[test]
    fn table_sorted_without_duplicates() {
        for w in ISO_METRIC_THREADS.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            assert!(
                a.nominal_diameter_mm < b.nominal_diameter_mm
                    || (a.nominal_diameter_mm == b.nominal_diameter_mm && a.pitch_mm > b.pitch_mm),
                "{} before {}",
                a.designation,
                b.designation
            );
        }
        let mut names: Vec<_> = ISO_METRIC_THREADS.iter().map(|t| t.designation).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), ISO_METRIC_THREADS.len());
        // Exactly one coarse pitch per diameter, and every designation parses to its own row.
        for t in ISO_METRIC_THREADS {
            let coarse = ISO_METRIC_THREADS
                .iter()
                .filter(|u| u.nominal_diameter_mm == t.nominal_diameter_mm && u.coarse)
                .count();
            assert_eq!(coarse, 1, "{}", t.designation);
            assert_eq!(parse_thread(t.designation), Some(t));
            assert_eq!(t.designation.contains('x'), !t.coarse);
        }
    }

    #[test]
    fn mu_tot_inverts_the_model() {
        // With equal coefficients the ISO 16047 evaluation returns mu up to the rounding of its
        // constants (0.16 vs 1/(2 pi), 0.58 vs 0.578): below 1e-3 for every thread at mu <= 0.3
        // (largest on M3, 6e-4), well inside the 0.003 accuracy asked of the estimator.
        for t in ISO_METRIC_THREADS {
            let g = JointGeometry::from(t);
            for mu in [0.08, 0.14, 0.3] {
                let est = g.mu_tot(g.torque_per_force(mu, mu));
                assert!((est - mu).abs() < 1e-3, "{} mu {mu}: {est}", t.designation);
            }
        }
        let m10 = JointGeometry::from(parse_thread("M10").unwrap());
        // K = T/(F d): 0.2 is the textbook nut factor near mu = 0.14.
        let k = m10.nut_factor(m10.torque_per_force(0.14, 0.14));
        assert!((0.17..0.21).contains(&k), "{k}");
    }

    #[test]
    fn torque_per_force_m8() {
        let m8 = parse_thread("M8").unwrap();
        let k = m8.torque_per_force(0.14, 0.14);
        let expected = 0.16 * 1.25 + 0.58 * m8.d2_mm * 0.14 + 10.315 / 2.0 * 0.14;
        assert!((k - expected).abs() < 1e-12);
    }
}
