"""iiwa-ident."""
