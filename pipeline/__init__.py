"""Drivers that run the product end to end: train, evaluate, then tabulate and plot with
analysis/ (which only reads the store). `make paper` calls `python -m pipeline.paper`."""
