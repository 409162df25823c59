"""SVSS processing, in the order a ping goes through it: :mod:`.conditioning` (matched
filter and baseband), :mod:`.imaging` (backprojection into tiles), :mod:`.products`
(background, compression, projections, detections), :mod:`.tiles` (the tile and its file
format) and :mod:`.worker` (pings in, tile files out)."""
