"""Configuration files and option bounds: structure TOML, GNSS run config, limits."""
