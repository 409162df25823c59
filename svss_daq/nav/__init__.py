"""Navigation, one job a module: geodesy, DVL geometry, instrument records, headings,
the fusion and the collecting navigator. ``svss_daq.navigation`` re-exports the public names."""
