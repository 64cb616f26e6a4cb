#!/bin/bash
# same_outputs_diff.sh A B: the files that differ between two same_outputs.sh folders, after
# normalising the output paths, the exports' commit stamp, the elapsed-time prefixes and the
# completion order of progress lines (prints only "compared" when they are the same).
A=$1; B=$2
norm() { sed -E "s#$2#OUT#g; s/^\[ *[0-9.]+ s\]/[T]/; s/commit [0-9a-f]{7,40}/commit C/g; s/\"commit\": \"[0-9a-f]+\"/\"commit\": \"C\"/; s/[0-9]+(\.[0-9]+)? s of CPU/T s of CPU/g; s/fit [0-9]+\/[0-9]+ done/fit k done/" "$1"; }
cd "$A"; for f in $(find . -type f ! -name '.clm-sim-manifest.json' | sort); do
  if [ ! -f "$B/$f" ]; then echo "only in A: $f"; continue; fi
  cmp -s "$A/$f" "$B/$f" && continue
  case "$f" in
    *.stdout) diff -q <(norm "$A/$f" "$A" | sort) <(norm "$B/$f" "$B" | sort) >/dev/null || echo "differs: $f";;
    *.h|*.json|*.md|*.c) diff -q <(norm "$A/$f" "$A") <(norm "$B/$f" "$B") >/dev/null || echo "differs: $f";;
    *.onnx) python3 - "$A/$f" "$B/$f" <<'P' || echo "differs: $f"
import sys, re
a, b = (open(p, "rb").read() for p in sys.argv[1:])
strip = lambda x: re.sub(rb"[0-9a-f]{12}", b"C", x)
sys.exit(0 if strip(a) == strip(b) else 1)
P
    ;;
    *) echo "differs: $f";;
  esac
done
(cd "$B"; find . -type f ! -name '.clm-sim-manifest.json') | while read f; do [ -f "$A/$f" ] || echo "only in B: $f"; done
echo "compared"
