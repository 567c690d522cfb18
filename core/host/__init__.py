"""The plugin host: hook specifications, the registry that builds plugins from config, and the contracts."""
