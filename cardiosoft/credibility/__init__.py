"""The credibility report (issue #42): the project's evidence recomputed and laid out in the
structure of ASME V&V 40 (2018), one module per credibility factor.

- :mod:`~cardiosoft.credibility.context`: the contexts of use and their model risk;
- :mod:`~cardiosoft.credibility.code_verification`: closed forms and peers of the blocks, the
  solver's observed order, conservation;
- :mod:`~cardiosoft.credibility.calculation_verification`: per scene, the error the default
  preset leaves (what ``--verify`` estimates, next to the true error) and the steady state;
- :mod:`~cardiosoft.credibility.validation`: every comparison with the paper, fitted or held
  out, with the comparators' uncertainty and the model's bands;
- :mod:`~cardiosoft.credibility.applicability`: where that evidence stands relative to each
  context of use;
- :mod:`~cardiosoft.credibility.report` computes them (reusing a section whose inputs are
  unchanged) and writes the page with the verdict table on top;
  :mod:`~cardiosoft.credibility.cli` is ``cardiosoft credibility``.
"""
