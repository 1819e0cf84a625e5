//! Detect every dot of a dot target using prior knowledge of its lattice
