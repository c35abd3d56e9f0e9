"""The loop's profile on the real-noise pairs with some of its components only: where its gain comes from.

    python benchmarks/real_noise/run.py --out runs/real_noise     # first: the loop's profile there
    python benchmarks/real_noise/variants.py "loop: ReadDist only" "loop: read side only"

Rows: "loop: ReadDist only" (the base model, its colour bias included, with the measured
read-noise distribution and nothing else the loop added), "loop: read side only" (without
the ADC-side Clip and CodeMap). Same recipe and seeds (0-2) as run.py; results in
runs/exp/real_diag/.
"""
import sys
from pathlib import Path

from rawaug import NoiseProfile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import run as R  # noqa: E402
src = Path('runs/real_noise')  # run.py's --out (the README's)
out = Path('runs/exp/real_diag'); out.mkdir(parents=True, exist_ok=True)
loop = NoiseProfile.load(src / 'loop_profile.yaml').to_dict()
variants = {"loop: ReadDist only": ["ReadDist"], "loop: read side only": ["FPN", "Hot", "ReadDist", "LowFreq"]}
R.MODELS.update({row: R.MODELS["loop"] for row in variants})  # the loop row's base model, colour bias included
profiles = {}
for row, keep in variants.items():
    d = {**loop, "effects": {k: v for k, v in loop["effects"].items() if k in keep}}
    profiles[row] = out / (row.replace(':', '').replace(' ', '_') + '.yaml')
    NoiseProfile.from_dict(d).save(profiles[row])
scale = dict(R.SCALES['cpu'])
dark = R.read_dark(R.DARK); cut = dark.shape[1] * 2 // 3
pairs = R.test_pairs(dark[:, cut:], scale)
for row in sys.argv[1:]:
    for seed in (0, 1, 2):
        res = R.train_and_test(row, seed, out, profiles, dark[:, :cut], pairs, scale)
        print(row, seed, {k: round(v, 2) for k, v in res['psnr'].items()}, flush=True)
