"""The ``icl-nuim`` dataset: ICL-NUIM living-room and office scenes fused from depth frames."""
