//! `rogs::fuzzing::importers`: any bytes, refused or read, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| rogs::fuzzing::importers(data));
