"""Training of a small SPAR on procedural rooms (issue 6): the semantic teacher (seeded CLIP
text encoder + small LSeg trained to predict class-name embeddings), and SPAR itself with the
paper's self-supervised losses. See training/README.md."""
