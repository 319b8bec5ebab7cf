//! The catalogue of malformed bundles (`rogs example --malformed`, one thing broken per
//! case) through `rogs inspect` and `rogs reconstruct`: each is refused with exit code
//! 3 (bad input) before any work, by a message line that names the field or file and
//! states the rule. The page tests drop the same cases on the page.
#![cfg(not(target_arch = "wasm32"))]

use std::process::Command;

fn rogs(args: &[&str]) -> (Option<i32>, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_rogs"))
        .args(args)
        .output()
        .expect("run rogs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.code(), text)
}

#[test]
fn every_malformed_bundle_is_refused_by_inspect_and_reconstruct_naming_its_cause() {
    let dir = std::env::temp_dir().join(format!("rogs-catalogue-{}", std::process::id()));
    let (code, text) = rogs(&["example", "--malformed", "--out", dir.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{text}");
    let cases = rogs::bundle::catalogue::catalogue().expect("catalogue");
    assert!(cases.len() >= 50, "{} cases", cases.len());
    let mut failures = Vec::new();
    for c in &cases {
        let zip = dir.join(format!("{}.zip", c.name));
        let zip = zip.to_str().unwrap();
        let out = dir.join(format!("{}-out", c.name));
        for (what, args) in [
            ("inspect", vec!["inspect", zip]),
            (
                "reconstruct",
                vec!["reconstruct", zip, "--out", out.to_str().unwrap()],
            ),
        ] {
            let (code, text) = rogs(&args);
            let named = text
                .lines()
                .any(|l| l.contains(c.names) && l.contains(c.says));
            if code != Some(3) || !named {
                failures.push(format!(
                    "{} ({}), rogs {what}: exit {code:?}, expected 3 and a line naming {:?} with {:?}:\n{text}",
                    c.name, c.breaks, c.names, c.says
                ));
            }
            // Nothing of a map is written for a refused bundle.
            if out.join("report.json").exists() {
                failures.push(format!("{}: rogs {what} wrote a map", c.name));
            }
        }
    }
    std::fs::remove_dir_all(&dir).ok();
    assert!(
        failures.is_empty(),
        "{} of {} checks failed:\n{}",
        failures.len(),
        2 * cases.len(),
        failures.join("\n")
    );
}
