//! The number types a channel can hold, shared by every layer: a curve is read as `f32` or
//! `f64` where Arrow left it, and widened to `f64` sample by sample for arithmetic.

/// A number type a channel can hold.
pub trait Sample: Copy + Send + Sync + 'static {
    /// Widens to `f64` for arithmetic.
    fn to_f64(self) -> f64;
}
impl Sample for f32 {
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
}
impl Sample for f64 {
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
}
