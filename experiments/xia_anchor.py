"""The anchor of the measured-radar experiments: Xia et al.'s own DTI CNN (the ONNX export in their repository)
scored on their held-out users A and B, with the rows read exactly as the measured preset reads them.

    python -m experiments.xia_anchor [--onnx PATH] [--manifest conf/manifests/xia2021.yaml]

Needs ``onnxruntime`` (``pip install onnxruntime``; not a dependency of handradar) and the mirror's
``OpenSource/CNN/DTI_CNN_Net.onnx`` (``handradar-fetch dataset=xia2021`` fetches it into data/xia2021). The
network takes the raw uint8 image as float (1, 1, 64, 64) and its 8 outputs follow MATLAB's categorical
order, the class names sorted alphabetically. Prints one line per test split and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from handradar.data.measured import list_rows, read_image, read_manifest
from handradar.provenance import REPO_ROOT


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(REPO_ROOT / "conf" / "manifests" / "xia2021.yaml"))
    ap.add_argument("--onnx", default=None, help="DTI_CNN_Net.onnx (default: under the manifest's root)")
    args = ap.parse_args(argv)
    import onnxruntime as ort

    m = read_manifest(args.manifest)
    onnx = Path(args.onnx) if args.onnx else m.root / "OpenSource" / "CNN" / "DTI_CNN_Net.onnx"
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    net = ort.InferenceSession(str(onnx), options)
    classes = list(m.classes)
    output_order = sorted(classes)  # MATLAB's categorical order
    for split in m.test:
        rows = [(y, f) for s, y, f in list_rows(m) if s == split]
        x = np.stack([read_image(f).astype(np.float32) for _, f in rows])[:, None]
        logits = np.concatenate([net.run(None, {net.get_inputs()[0].name: x[i:i + 1]})[0] for i in range(len(x))])
        predicted = [classes.index(output_order[k]) for k in logits.argmax(axis=1)]
        acc = float(np.mean(np.asarray(predicted) == np.asarray([y for y, _ in rows])))
        print(f"{m.name} {split}: their DTI CNN {acc:.3f} on {len(rows)} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
