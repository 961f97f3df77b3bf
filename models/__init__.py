"""The bundled model files (installed as ``casest._models``; see ``casest.load_model_file``)."""
