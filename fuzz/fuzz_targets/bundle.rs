//! Any bytes as a dropped bundle: opening them may refuse them, never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let limits = rogs::bundle::Limits {
        decode_images: true,
        ..Default::default()
    };
    let _ = rogs::bundle::Bundle::from_zip_bytes(data.to_vec(), limits);
});
