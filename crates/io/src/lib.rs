//! Image I/O for real camera files: TIFF (8/12/16-bit, float, compressed, tiled, multi-page), PNG, masks
