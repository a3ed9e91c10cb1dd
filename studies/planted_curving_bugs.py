"""Plant curving bugs in copies of the repository and record which curving tests fail.

    python studies/planted_curving_bugs.py [BUG ...]

Each bug is a textual edit of a copy in a temporary folder (the repository is not touched);
the tests run with NUMBA_DISABLE_JIT=1 (no compile per copy; about a minute per bug). The
results are listed in docs/model.md Section 11.
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = str(Path(__file__).resolve().parent.parent)
BUGS = [
    ("e_over_R_sign", "bogie_env/dynamics.py",
     [("xi_x_left = -lam * y_rel / r0 - e * dpsi * inv_v - e * kappa", "xi_x_left = -lam * y_rel / r0 - e * dpsi * inv_v + e * kappa"),
      ("xi_x_right = lam * y_rel / r0 + e * dpsi * inv_v + e * kappa", "xi_x_right = lam * y_rel / r0 + e * dpsi * inv_v - e * kappa")]),
    ("cant_sign", "bogie_env/dynamics.py",
     [("return V * V * kappa * cos_cant - GRAVITY * sin_cant", "return V * V * kappa * cos_cant + GRAVITY * sin_cant")]),
    ("no_gravity_term", "bogie_env/dynamics.py",
     [("return V * V * kappa * cos_cant - GRAVITY * sin_cant", "return V * V * kappa * cos_cant")]),
    ("radius_in_km_route", "bogie_env/route.py",
     [("return kind, length, sign / radius, sign * cant", "return kind, length, sign / (radius * 1000.0), sign * cant")]),
    ("radius_in_km_cli", "bogie_env/analysis/curving.py",
     [("return sign / radius_m, sign * cant_m", "return sign / (radius_m * 1000.0), sign * cant_m")]),
    ("no_car_body_share", "bogie_env/dynamics.py",
     [("- (p[P_MB] + carried) * accel_b) / p[P_MB]", "- p[P_MB] * accel_b) / p[P_MB]")]),
    ("no_frame_offset_C6", "bogie_env/dynamics.py",
     [("spring_y = Kpy2 * (x[o] + offset - yb - side * L1 * psib)", "spring_y = Kpy2 * (x[o] - yb - side * L1 * psib)")]),
    ("no_heading_C6", "bogie_env/dynamics.py",
     [("yaw_moment = yaw_k * (x[o + 4] + heading - psib)", "yaw_moment = yaw_k * (x[o + 4] - psib)")]),
]
parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("bugs", nargs="*", metavar="BUG",
                    help="bugs to plant (default: all): " + ", ".join(name for name, _, _ in BUGS))
only = parser.parse_args().bugs
unknown = sorted(set(only) - {name for name, _, _ in BUGS})
if unknown:
    parser.error(f"unknown bug(s) {', '.join(unknown)}")
files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True).stdout.split()
for name, path, edits in BUGS:
    if only and name not in only:
        continue
    dest = tempfile.mkdtemp(prefix=f"plant_{name}_")
    shutil.rmtree(dest, ignore_errors=True)
    for f in files:
        os.makedirs(os.path.dirname(os.path.join(dest, f)) or dest, exist_ok=True)
        shutil.copy2(os.path.join(ROOT, f), os.path.join(dest, f))
    text = open(os.path.join(dest, path)).read()
    for old, new in edits:
        assert text.count(old) == 1, (name, old)
        text = text.replace(old, new)
    open(os.path.join(dest, path), "w").write(text)
    env = dict(os.environ, PYTHONPATH=dest, NUMBA_DISABLE_JIT="1")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_curving.py", "tests/test_route.py"],
                          cwd=dest, env=env, capture_output=True, text=True)
    failed = sorted(set(re.findall(r"FAILED (\S+?)(?: - |$)", done.stdout, re.M)))
    print(f"## {name}: {len(failed)} failed", flush=True)
    for f in failed:
        print("   ", f, flush=True)
    print("   ", done.stdout.strip().splitlines()[-1], flush=True)
    shutil.rmtree(dest, ignore_errors=True)
