"""The project's default configuration files (YAML), installed as the package ``recon_core.default_config``.

Nothing to import here: ``recon_core.config.CONFIG_DIR`` locates this folder through package
resources in every kind of install (editable, wheel, colcon/ament).
"""
