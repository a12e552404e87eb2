"""Evaluation of SPAR on procedural test scenes (PROTOCOL.md): metrics, protocol, the PyTorch
reference runner, and tools to compare and tabulate result files."""
