"""SVSS processing: conditioning, 3-D backprojection into tiles, image products."""
