#!/usr/bin/env python3
"""Packs a fuzz target's corpus folder (after `cargo fuzz cmin`) into
fuzz/corpus/TARGET.zip, smallest inputs first up to a byte budget, which
tests/fuzz_corpus.rs replays in CI. Unpack it to go on fuzzing from it:
    unzip fuzz/corpus/TARGET.zip -d /tmp/corpus-TARGET
    cd fuzz && RUSTC_BOOTSTRAP=1 cargo fuzz run -O TARGET /tmp/corpus-TARGET

usage: scripts/pack-fuzz-corpus.py TARGET FOLDER [BUDGET_BYTES]
"""
import os
import sys
import zipfile

target, folder = sys.argv[1], sys.argv[2]
budget = int(sys.argv[3]) if len(sys.argv) > 3 else 1 << 20
files = sorted((os.path.getsize(os.path.join(folder, f)), f) for f in os.listdir(folder))
root = os.path.join(os.path.dirname(__file__), '..', 'fuzz', 'corpus')
os.makedirs(root, exist_ok=True)
total = kept = 0
with zipfile.ZipFile(os.path.join(root, f'{target}.zip'), 'w', zipfile.ZIP_DEFLATED) as z:
    for size, name in files:
        if total + size > budget:
            break
        info = zipfile.ZipInfo(name, date_time=(2026, 1, 1, 0, 0, 0))
        info.compress_type = zipfile.ZIP_DEFLATED
        with open(os.path.join(folder, name), 'rb') as f:
            z.writestr(info, f.read())
        total += size
        kept += 1
print(f'{target}: kept {kept} of {len(files)} inputs, {total} bytes')
