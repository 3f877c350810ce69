"""Time eos's ``fit_shape_and_pose`` on given 68-point landmarks (run with an eos-py interpreter).

    EOS_SHARE=/path/to/eos/share python benchmarks/eos_timing.py landmarks.json

Not part of facegeo: :mod:`bench_fit_speed` runs it in a separate virtual environment that has
``eos-py`` (pip install eos-py numpy) and eos's ``share/`` folder (the Surrey Face Model
``sfm_shape_3448.bin``, ``expression_blendshapes_3448.bin``, ``ibug_to_sfm.txt``, the edge
topology and the model contours, from eos's repository). Input: a JSON list of
``{"points": [[x, y] * 68], "width": W, "height": H}``; output (stdout): a JSON list of CPU seconds
per fit, in input order, each the fit alone (model files loaded once before).
"""

from __future__ import annotations

import json
import os
import sys
import time

import eos


def main() -> None:
    share = os.environ["EOS_SHARE"]
    shape_model = eos.morphablemodel.load_model(f"{share}/sfm_shape_3448.bin")
    blendshapes = eos.morphablemodel.load_blendshapes(f"{share}/expression_blendshapes_3448.bin")
    model = eos.morphablemodel.MorphableModel(shape_model.get_shape_model(), blendshapes, color_model=eos.morphablemodel.PcaModel(),
                                              vertex_definitions=None, texture_coordinates=shape_model.get_texture_coordinates())
    mapper = eos.core.LandmarkMapper(f"{share}/ibug_to_sfm.txt")
    topology = eos.morphablemodel.load_edge_topology(f"{share}/sfm_3448_edge_topology.json")
    contour = eos.fitting.ContourLandmarks.load(f"{share}/ibug_to_sfm.txt")
    model_contour = eos.fitting.ModelContour.load(f"{share}/sfm_model_contours.json")
    seconds = []
    for case in json.load(open(sys.argv[1])):
        landmarks = [eos.core.Landmark(str(i + 1), [float(x), float(y)]) for i, (x, y) in enumerate(case["points"])]
        t0 = time.process_time()
        eos.fitting.fit_shape_and_pose(model, landmarks, mapper, case["width"], case["height"], topology, contour, model_contour)
        seconds.append(time.process_time() - t0)
    print(json.dumps(seconds))


if __name__ == "__main__":
    main()
