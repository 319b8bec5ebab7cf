//! Any bytes as a tile checkpoint: decoding may refuse them, never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = rogs::tiles::checkpoint::decode(data);
});
