"""First (uncached) versus second (cached) load of a model library: python scripts/bench_cache.py [FOLDER]."""
import sys
import tempfile
import time
from pathlib import Path

from pcdet.library import ModelLibrary

folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent / "models"
with tempfile.TemporaryDirectory() as cache:
    t0 = time.perf_counter()
    ModelLibrary.from_folder(folder, cache_dir=cache)
    t1 = time.perf_counter()
    ModelLibrary.from_folder(folder, cache_dir=cache)
    t2 = time.perf_counter()
print(f"| library | first load (s) | second load (s) | ratio |\n|---|---|---|---|\n"
      f"| {folder.name} | {t1 - t0:.3f} | {t2 - t1:.4f} | {(t1 - t0) / (t2 - t1):.0f}x |")
