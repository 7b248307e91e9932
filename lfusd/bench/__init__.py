"""The light-field video scene-flow benchmark: ``lfusd bench make|oracle|score|baseline``.

- :mod:`lfusd.bench.make`: frozen definitions (``definitions/<name>.toml``: a dataset recipe with
  parts ``train``, ``val`` and ``test``, and ``definitions/<name>.digests.json``: the sha256 of
  every generated stage, so a change of the generators is caught before anything renders), and
  the benchmark folder: ``render/`` (the recipe's dataset), ``public/`` (train and val with ground
  truth, test with rgb and cameras only), ``gt/`` (the test ground truth and its digests), a card.
- :mod:`lfusd.bench.score`: the submission format, its checks, the oracle and the scorer.
- :mod:`lfusd.bench.baseline`: baseline (a), per-view DIS flow and plane-sweep disparity composed
  into scene flow, written as a submission from the public test inputs only.
"""
