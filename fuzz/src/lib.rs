//! Shared glue of the `cargo fuzz` targets: [`target!`] defines a libFuzzer target for one
//! `r2human::fuzzing::Target`, the same loader call and property as the stable harness (`tests/fuzz.rs`).

#[doc(hidden)]
pub use libfuzzer_sys;

/// Defines the libFuzzer entry point and mutator for a `r2human::fuzzing::Target`: each input runs through
/// `r2human::fuzzing::fuzz_one` (a panic or a property violation is a crash); half of the mutations are
/// libFuzzer's own, half `r2human::fuzzing::mutate` (structure-aware: GLB containers rebuilt, PNG checksums
/// repaired, dictionary tokens, numbers out of range).
#[macro_export]
macro_rules! target {
    ($target:expr) => {
        $crate::libfuzzer_sys::fuzz_target!(|data: &[u8]| {
            r2human::fuzzing::fuzz_one($target, data);
        });

        $crate::libfuzzer_sys::fuzz_mutator!(|data: &mut [u8], size: usize, max_size: usize, seed: u32| {
            if seed % 2 == 0 {
                $crate::libfuzzer_sys::fuzzer_mutate(data, size, max_size)
            } else {
                r2human::fuzzing::mutate_in_place($target, data, size, max_size, seed as u64)
            }
        });
    };
}
