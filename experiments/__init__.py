"""The paper's experiments, one module each; `vprsnn-export experiment NAME` runs them.

Each module defines ``NAME``, ``DESCRIPTION``, ``run(settings) -> dict`` (JSON-ready
results) and ``render(results, out_dir) -> str`` (Markdown, plots beside it).
"""
