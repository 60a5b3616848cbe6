"""`graphsvc report`: a self-contained HTML page with a 3D viewer of a reconstruction
(and its truth) and time-aligned charts: gather (the arrays of one clip), load (a
synthesize report, an evaluation with kept motions, a batch folder), html (the page)."""
