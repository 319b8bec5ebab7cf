//! The fuzzing corpus kept in `fuzz/corpus/TARGET.zip` (minimised by `cargo fuzz cmin` from the
//! coverage-guided runs docs/RELIABILITY.md lists), replayed through the same
//! functions the fuzz targets call (`rogs::fuzzing`), then a short mutation run from
//! it: bit flips, byte changes, cuts, repeats and truncations, seeded so a failure
//! reproduces. CI has no cargo-fuzz (it needs a nightly compiler's flags); this is its
//! short fuzz run. A panic fails the test and names the input.
#![cfg(not(target_arch = "wasm32"))]

use rogs::synth::rng::Rng;

fn corpus(target: &str) -> Vec<(String, Vec<u8>)> {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/corpus")
        .join(format!("{target}.zip"));
    let file = std::fs::File::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut z = zip::ZipArchive::new(file).expect("a corpus zip");
    (0..z.len())
        .map(|i| {
            let mut e = z.by_index(i).expect("a corpus entry");
            let mut b = Vec::new();
            std::io::Read::read_to_end(&mut e, &mut b).expect("read a corpus entry");
            (e.name().map(|n| n.to_string()).unwrap_or_default(), b)
        })
        .collect()
}

fn mutate(rng: &mut Rng, data: &mut Vec<u8>) {
    let mut pick = |n: usize| (rng.next_u64() % n.max(1) as u64) as usize;
    for _ in 0..1 + pick(4) {
        let n = data.len();
        match pick(6) {
            0 if n > 0 => data[pick(n)] ^= 1 << pick(8),
            1 if n > 0 => data[pick(n)] = pick(256) as u8,
            2 if n > 1 => {
                let a = pick(n);
                let b = (a + 1 + pick(64)).min(n);
                data.drain(a..b);
            }
            3 if n > 1 => {
                let a = pick(n);
                let b = (a + 1 + pick(64)).min(n);
                let piece = data[a..b].to_vec();
                let at = pick(n);
                data.splice(at..at, piece);
            }
            4 => data.truncate(pick(n + 1)),
            _ => data.insert(pick(n + 1), pick(256) as u8),
        }
    }
}

fn run(target: &str, mutations: usize) {
    let f = rogs::fuzzing::TARGETS
        .iter()
        .find(|(n, _)| *n == target)
        .expect("a fuzz target")
        .1;
    let inputs = corpus(target);
    assert!(!inputs.is_empty(), "fuzz/corpus/{target}.zip is empty");
    let bytes: usize = inputs.iter().map(|(_, b)| b.len()).sum();
    println!(
        "{target}: {} corpus inputs ({bytes} bytes), {mutations} mutations",
        inputs.len()
    );
    for (path, bytes) in &inputs {
        let r = std::panic::catch_unwind(|| f(bytes));
        assert!(r.is_ok(), "{target}: corpus input {path} panicked");
    }
    let mut rng = Rng::new(0x5eed ^ target.len() as u64);
    for k in 0..mutations {
        let (path, bytes) = &inputs[(rng.next_u64() % inputs.len() as u64) as usize];
        let mut m = bytes.clone();
        mutate(&mut rng, &mut m);
        let r = std::panic::catch_unwind(|| f(&m));
        assert!(
            r.is_ok(),
            "{target}: mutation {k} of corpus input {path} panicked (seeded: rerun this test to reproduce)"
        );
    }
}

#[test]
fn importers_corpus_and_mutations() {
    run("importers", 200_000);
}

#[test]
fn map_file_corpus_and_mutations() {
    run("map_file", 5_000);
}

#[test]
fn bundle_corpus_and_mutations() {
    run("bundle", 5_000);
}

#[test]
fn checkpoint_corpus_and_mutations() {
    run("checkpoint", 20_000);
}
