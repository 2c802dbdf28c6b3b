from controller.launch import entry

entry()
