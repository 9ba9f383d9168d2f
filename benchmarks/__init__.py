"""The asv benchmark suite (``asv.conf.json``): each benchmark times the package beside
its peer (OpenCV, bare Embree) in the same process, and tracks their ratio.

Run it in the project's ``.venv``, without asv building environments::

    .venv/bin/asv run --python=same --quick      # one pass, the current checkout
    .venv/bin/asv run --python=same              # full timing, results in .asv/results

The ``bench/bench_*.py`` scripts are the long forms: more cases, the accuracy against the
truth, and the history in ``docs/benchmark_history.md``.
"""
