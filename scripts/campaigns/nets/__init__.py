"""The global-optimum nets the campaigns and tests check casest against: generated separable
problems (`optimum_net`), the published NIST StRD problems (`published_net`), and brute-force
references of their concentrated cost (`references`). Not part of the installed package."""
