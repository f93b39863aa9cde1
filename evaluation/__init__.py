"""lostx.evaluation: how well it recognises places, measured.

- :mod:`.groundtruth`: which reference frames show each query's place;
- :mod:`.metrics`: precision, recall, recall at 100 % precision, F1, Recall@N (docs/metrics.md);
- :mod:`.significance`: the interval of a recall measured on few queries, and two methods compared query by query;
- :mod:`.datasets`: reference/query pairs in the common formats, with their ground truth;
- :mod:`.methods`: LoST-X and the baselines run on a pair (``lostx eval``);
- :mod:`.report`: report.json, report.md and the figures.
"""
