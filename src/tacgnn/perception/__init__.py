"""Perception: from one tactile frame (readings and taxel positions) to an object's state.

* ``models/``: TacGNN and its baselines, built from one config (``models.build_model``).
* ``graph_ops``, ``graph_numba``: kNN and farthest point sampling (torch, numba).
* ``objectives``: what each task predicts, its loss and its reported errors.
* ``data``: a dataset in memory and its split; ``rest_positions``: taxels at rest.
* ``sequences``: episodes, windows of consecutive frames, the split by episode.
* ``train_config``, ``training``, ``checkpoint``: offline training and its files, one of each for
  single-frame and temporal models (a single-frame model reads windows of one frame).
* ``evaluation``: errors on a test split, with dead taxels or a lost patch, touched and untouched balls.
"""
