"""Runtime over generated packages: load a generated model package and run its
particle filters on recorded data (detection, isolation and identification build
on this)."""
