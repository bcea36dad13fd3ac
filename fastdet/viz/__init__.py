"""Pictures: drawing on frames (:mod:`.draw`, OpenCV only) apart from the figures.

:mod:`.draw` is what ``fastdet run`` needs on every frame.  The matplotlib
figures (``fastdet viz``, training reports, the benchmark's plots) live in
:mod:`.figure` and the ``*_figures`` modules, which need the ``viz`` extra;
nothing here imports them, so importing fastdet never imports matplotlib.
"""
