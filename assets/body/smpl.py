def load_smpl(path): raise NotImplementedError
