"""The OLNG strategy (Tautges et al. 2011): per sample the knowledge-base frames with the
nearest readings, an online lazy neighbourhood graph over the last M samples' neighbours
(`lattice`), and, from its cheapest paths, an optimised pose."""
