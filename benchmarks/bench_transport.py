"""View factors against a bare Embree call on the same rays (``bench/bench_viewfactors.py``)."""

from __future__ import annotations

from ._peers import ratio_of_best


class ViewFactorsVsEmbree:
    """The open corner of ``scenes.corner`` (resolution 30: 3,600 faces), 128 rays a face:
    ``selfillum.view_factors`` (sampling, tracing, sparse assembly) against one bare
    ``embreex`` run of the very same rays (tracing only: the ceiling)."""

    timeout = 300

    def setup(self):
        from bench_viewfactors import same_rays

        from scenes.corner import corner
        from selfillum import view_factors

        self.mesh = corner(resolution=30).mesh
        self.scene, self.o, self.d = same_rays(self.mesh, 128, 0)
        self.view_factors = view_factors
        self.view_factors(self.mesh, 8, seed=0)  # compiled kernels loaded before timing

    def time_view_factors(self):
        self.view_factors(self.mesh, 128, seed=0)

    def time_bare_embree(self):
        self.scene.run(self.o, self.d)

    def track_ratio_to_bare_embree(self):
        return ratio_of_best(lambda: self.view_factors(self.mesh, 128, seed=0),
                             lambda: self.scene.run(self.o, self.d))

    track_ratio_to_bare_embree.unit = "ours / bare Embree"
