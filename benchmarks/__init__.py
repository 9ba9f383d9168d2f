"""The asv benchmark suite (``asv.conf.json``): each benchmark times the package beside
its peer (OpenCV, bare Embree) in the same process, and tracks their ratio.

Run it in the project's ``.venv``, without asv building environments::

    .venv/bin/asv run --python=same --quick      # one pass, the current checkout
    .venv/bin/asv run --python=same              # full timing, results in .asv/results

The size of the issue-size benchmarks is ``WTO_BENCH_SIZE`` (``small`` by default, or
``issue``); ``WTO_BENCH_BASELINE`` names another checkout to run beside (``_peers.py``).
The figures measured before the suite, by the former ``bench/`` scripts, are in
``docs/benchmark_history.md``.
"""
