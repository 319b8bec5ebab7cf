//! guard: the test that keeps a NaN out of the model. The kernels that produce
//! gradients (`project_backward`, `regularise`) raise a status word when one of theirs
//! is not `usable`, and `adam` then applies nothing. With finite parameters and
//! moments, valid constants (checked on the host) and usable gradients, Adam's update
//! is finite: |g| < 1e18 keeps g² finite, and the step is bounded by a few learning
//! rates. The test reads the bit pattern because WGSL lets compilers assume that NaN
//! and Inf never occur in float comparisons.

fn usable(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u && abs(x) < 1e18;
}
