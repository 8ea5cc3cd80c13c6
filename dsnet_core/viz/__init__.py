"""Small pictures for reports: a zlib PNG writer and bird's-eye-view rasters (numpy only)."""
