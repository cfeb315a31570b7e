"""The reproduction layer: the paper's grid of runs (:mod:`~transam.reproduce.grid`, locally or
on a Ray cluster with :mod:`~transam.reproduce.grid_ray`) and the report built from its run
directories (:mod:`transam.reproduce.report`). It sits on top of training and evaluation and
nothing below imports it.
"""
