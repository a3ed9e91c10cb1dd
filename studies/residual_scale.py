"""A distilled residual student with its correction's authority scaled: the same network, the
same baseline, ``residual.scale`` set to ``--scale`` (0 < s <= 1), or to a schedule over speed
(``--scale 1@300,0.25@400``: full authority up to 300 km/h, a quarter from 400, linear in
between; ``distilled.checked_scale``). The copy is a student folder that
``bogie evaluate --policy OUT --trust-policy`` runs like any other.

The scale multiplies the network's command before it is added to the baseline's
(``agents.controllers.distilled.ResidualFrames``), so it asks how much of the correction each
protocol column wants, without training again. Choose a scale on a validation block of seeds
(``bogie evaluate --seed 10``: seeds 10-19, none shared with the protocol's) and report it on the
protocol's seeds (``--seed 0``: seeds 0-9), not the other way round.

    python studies/residual_scale.py --policy RUN/iterations/005 --scale 0.5 --out /tmp/res_s05
    python studies/residual_scale.py --policy RUN/iterations/005 --scale 1@300,0.25@400 --out /tmp/res_sched
    bogie evaluate --policy /tmp/res_s05 --trust-policy --parts critical --seed 10 --json --out val.json
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

from bogie_agents.controllers.distilled import META_FILE, WEIGHTS_FILE, checked_scale, load_student
from bogie_env.params import ConfigError


def parse_scale(text: str) -> float | dict[str, list[float]]:
    """``0.5``, or ``S@V,S@V,...`` (authority at speed in km/h) as a schedule."""
    try:
        if "@" not in text:
            return checked_scale(float(text), "--scale")
        pairs = [item.split("@") for item in text.split(",")]
        return checked_scale({"speeds_kmh": [float(v) for _, v in pairs], "scales": [float(s) for s, _ in pairs]}, "--scale")
    except ValueError:
        raise ConfigError(f"--scale = {text!r}; allowed: a number in (0, 1], or S@V,S@V,... at increasing speeds V (km/h)") from None


def scaled_copy(policy: str | Path, scale: float | dict, out: str | Path) -> Path:
    """Write ``policy`` (a residual student folder) to ``out`` with ``residual.scale = scale``;
    the copy is checked by loading it. ``out`` is written whole or not at all."""
    policy, out = Path(policy), Path(out)
    meta = json.loads((policy / META_FILE).read_text())
    if meta.get("residual") is None:
        raise ConfigError(f"{policy / META_FILE}: 'residual' is missing; allowed: a residual student (a baseline under it)")
    scale = checked_scale(scale, "--scale")
    meta["residual"]["scale"] = scale
    meta["residual_scale_of"] = {"policy": str(policy), "trained_scale": meta.get("config", {}).get("student", {}).get("residual", {}).get("scale")}
    if out.exists():
        raise FileExistsError(f"--out {out} exists; choose a new folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=out.name + ".", dir=out.parent))
    try:
        shutil.copy2(policy / WEIGHTS_FILE, tmp / WEIGHTS_FILE)
        (tmp / META_FILE).write_text(json.dumps(meta, indent=1))
        load_student(tmp)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", required=True, help="a residual student folder (RUN/iterations/NNN)")
    parser.add_argument("--scale", type=parse_scale, required=True, help="the correction's authority: 0 < s <= 1, or S@V,S@V,... over speed")
    parser.add_argument("--out", required=True, help="a new folder")
    args = parser.parse_args()
    print(scaled_copy(args.policy, args.scale, args.out))


if __name__ == "__main__":
    main()
