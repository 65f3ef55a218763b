"""What runs beside a plant: ``monitor`` (a stream of rows diagnosed as
they arrive, ``bgc monitor``)."""
