"""Eclipse SUMO as a navigation backend (libsumo): networks built from the roadmap, lanes,
and the SUMO world. Importing this package never imports libsumo."""
