"""Sweeps: an experiment times a grid of overrides (:mod:`.grid`), the vectorised analytic lanes
that run many points at once (:mod:`.lanes`), points whose programs differ only in numbers
built once with a value per point (:mod:`.shared_build`, :mod:`.traced`), and the resumable
store of finished points (:mod:`.store`), for `mgpusim sweep` and :func:`mgpusim.sweep`; the
plot drawn by a process of its own (:mod:`.plotter`), and one recording profile per profile for
the unused-override check of the points (:mod:`.reads`)."""
