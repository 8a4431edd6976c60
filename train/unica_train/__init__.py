"""The unica trainer: reads datasets baked by `unica bake`, trains the geometry model and
writes bundles that the Rust app loads. See train/README.md."""
