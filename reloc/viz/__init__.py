"""Pictures (optional ``viz`` extra, matplotlib imported lazily): a depth frame with its planes and normals
(:func:`plot_frame_planes`), and a map from above with a relocalized submap at its estimated pose
(:func:`plot_map_topdown`, the paper's Fig. 4)."""

from reloc.viz.frames import plot_frame_planes
from reloc.viz.maps import plot_map_topdown, topdown_basis

__all__ = ["plot_frame_planes", "plot_map_topdown", "topdown_basis"]
