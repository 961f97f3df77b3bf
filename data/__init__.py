"""The bundled reference data (installed as ``casest._data``; see ``casest.bundled_data_dir``)."""
