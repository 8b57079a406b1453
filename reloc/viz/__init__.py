"""Pictures (optional ``viz`` extra, matplotlib imported lazily), each a PNG of an exact pixel size:

- :func:`plot_frame_planes`: a depth frame with its planes and normals;
- :func:`plot_map_topdown`: a map from above with a relocalized submap at its estimated pose (the paper's Fig. 4);
- :func:`plot_reloc_results`: every query of ``reloc locate`` on the map, coloured by outcome, with ground truth;
- :func:`plot_eval_bars`: precision and recall per scene / source / ablation with the outcome counts;
- :func:`plot_latency`: latency histograms per stage (p50, p95, p99 marked).
``reloc plot`` (:mod:`reloc.viz.cli`) makes them from the files the other commands write.
"""

from reloc.viz.evaluation import eval_panels, plot_eval_bars
from reloc.viz.frames import plot_frame_planes
from reloc.viz.latency import latency_data, plot_latency, stats_from_samples
from reloc.viz.maps import plot_map_topdown, topdown_basis
from reloc.viz.results import plot_reloc_results, read_results, result_kinds

__all__ = ["plot_frame_planes", "plot_map_topdown", "topdown_basis", "plot_reloc_results", "read_results",
           "result_kinds", "eval_panels", "plot_eval_bars", "latency_data", "plot_latency", "stats_from_samples"]
