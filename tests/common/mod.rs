//! Helpers shared by the native test suites.

use std::io::Read;

/// Every entry of a zip, inflated, in the archive's order: what the page's reader
/// returns entry by entry.
pub fn zip_entries(zip: &[u8]) -> Vec<(String, Vec<u8>)> {
    let mut a = zip::ZipArchive::new(std::io::Cursor::new(zip)).expect("zip");
    (0..a.len())
        .map(|i| {
            let mut f = a.by_index(i).expect("entry");
            let mut v = Vec::new();
            f.read_to_end(&mut v).expect("read");
            (f.name().expect("name").to_string(), v)
        })
        .collect()
}
