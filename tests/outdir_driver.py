"""A process that writes one run through the staging API, for the race and kill tests (no JAX: it starts fast).

    python outdir_driver.py DEST OWNER TAG GO [--in-place] [--force]

It prepares DEST for OWNER, writes its files (each holding TAG), prints "ready", waits for the file GO to
exist, commits, and prints "committed <seconds the commit took>". A refusal prints its one line to stderr and
exits 2. With --in-place DEST is the working folder (``--out .``), which is committed file by file.
"""

from __future__ import annotations

import os
import sys
import time

from outdir_world import light_import

FILES = [f"fig{i:02d}.png" for i in range(16)] + ["metrics.json", "report.md", "config.toml"]


def main(argv: list[str]) -> int:
    dest, owner, tag, go = argv[:4]
    od = light_import()
    if "--in-place" in argv:
        os.chdir(dest)
        dest = "."
    try:
        st = od.prepare(dest, owner, force="--force" in argv)
    except od.OutputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        for name in FILES:
            with open(os.path.join(st.tmp, name), "w") as fh:
                fh.write(f"{tag}:{name}\n" * 50)
        print("ready", flush=True)
        while not os.path.exists(go):
            pass
        t = time.perf_counter()
        try:
            st.commit()
        except od.OutputError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        print(f"committed {time.perf_counter() - t:.6f}", flush=True)
        return 0
    finally:
        st.discard()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
