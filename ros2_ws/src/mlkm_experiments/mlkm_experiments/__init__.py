"""Experiments and benchmarks: the paper reproduction and make bench (``mlkm paper``,
``mlkm bench``: see ``commands``). They use the product; the product never uses them."""
